// Small dense non-negative least squares (Lawson & Hanson, "Solving Least Squares Problems",
// 1974, ch. 23) and the least-distance programme it solves (ch. 23.4). Sized for contact
// problems in reduced coordinates: a few dozen rows, a few hundred columns.
#pragma once

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "dense_kernels.h"
#include "scratch.h"
#include "small_cholesky.h"

namespace softrom {

// How least_distance solves its NNLS: the least-squares subproblem on the passive columns
//  Qr:   by a column-pivoted Householder QR of the (rows x p) passive block, factored afresh
//        for each subproblem (nnls(); the reference solver's);
//  Gram: through the p x p Gram matrix G_p^T G_p = R^T R (nnls_cholesky(); the fast solver's).
//        Lawson-Hanson keeps the passive columns linearly independent, so the Gram matrix is
//        positive definite; its factor grows and shrinks with the set and never adds a
//        dependent column.
enum class NnlsSolve { Qr, Gram };

struct NnlsResult {
  Eigen::VectorXd u;
  bool converged = true;  // false when an iteration cap stopped it
};

// min |G u - d| subject to u >= 0, each least-squares subproblem by a column-pivoted QR
// (NnlsSolve::Qr).
//
// `guess` (optional, G.cols() entries) warm-starts the passive set with its positive entries:
// the least-squares solution on that set, pruned until positive, is a valid starting point
// for Lawson-Hanson, and a good guess (last solve's support) leaves little to do.
inline NnlsResult nnls(const Eigen::Ref<const Eigen::MatrixXd>& g,
                       const Eigen::Ref<const Eigen::VectorXd>& d, const double* guess = nullptr,
                       int max_iterations = 0) {
  const Eigen::Index n = g.cols();
  if (max_iterations <= 0) max_iterations = static_cast<int>(3 * n + 10);
  NnlsResult res;
  Eigen::VectorXd& u = res.u;
  u = Eigen::VectorXd::Zero(n);
  Eigen::VectorXd z(n);
  std::vector<char> passive(n, 0);
  const double tol = 1e-12 * std::max(1.0, g.cwiseAbs().maxCoeff() * d.cwiseAbs().maxCoeff());
  std::vector<Eigen::Index> idx;
  Eigen::MatrixXd gp;
  auto solve_passive = [&]() {
    idx.clear();
    for (Eigen::Index j = 0; j < n; ++j)
      if (passive[j]) idx.push_back(j);
    const Eigen::Index p = static_cast<Eigen::Index>(idx.size());
    z.setZero();
    // (An inner step can drop every passive variable, where multipliers fall below the
    // absolute 1e-14 floor, e.g. a body some 1e20 times lighter than a kilogram: the QR of
    // a matrix without columns read an empty vector's maximum and crashed. u = 0 then.)
    if (p == 0) return;
    gp.resize(g.rows(), p);
    for (Eigen::Index c = 0; c < p; ++c) gp.col(c) = g.col(idx[c]);
    const Eigen::VectorXd zp = gp.colPivHouseholderQr().solve(d);
    for (Eigen::Index c = 0; c < p; ++c) z[idx[c]] = zp[c];
  };
  if (guess != nullptr) {
    int limit = 0;
    for (Eigen::Index j = 0; j < n; ++j) passive[j] = guess[j] > 0.0 ? 1 : 0;
    for (int it = 0; it < static_cast<int>(n) + 1; ++it) {
      limit = 0;
      for (Eigen::Index j = 0; j < n; ++j) limit += passive[j];
      if (limit == 0) break;
      solve_passive();
      bool pruned = false;
      for (Eigen::Index j : idx)
        if (z[j] <= 0.0) {
          passive[j] = 0;
          pruned = true;
        }
      if (!pruned) {
        u = z;
        break;
      }
    }
    if (limit == 0) u.setZero();
  }
  Eigen::VectorXd w = g.transpose() * (d - g * u);
  int outer = 0;
  for (; outer < max_iterations; ++outer) {
    Eigen::Index t = -1;
    double best = tol;
    for (Eigen::Index j = 0; j < n; ++j)
      if (!passive[j] && w[j] > best) {
        best = w[j];
        t = j;
      }
    if (t < 0) break;
    passive[t] = 1;
    int inner = 0;
    for (; inner < max_iterations; ++inner) {
      solve_passive();
      bool all_positive = true;
      for (Eigen::Index j : idx)
        if (z[j] <= 0.0) all_positive = false;
      if (all_positive) {
        u = z;
        break;
      }
      // Step from u towards z until the first passive variable hits zero; drop it.
      double alpha = 1.0;
      for (Eigen::Index j : idx)
        if (z[j] <= 0.0) alpha = std::min(alpha, u[j] / (u[j] - z[j]));
      u += alpha * (z - u);
      for (Eigen::Index j : idx)
        if (u[j] <= 1e-14 * (1.0 + u.cwiseAbs().maxCoeff())) {
          u[j] = 0.0;
          passive[j] = 0;
        }
    }
    if (inner == max_iterations) res.converged = false;
    w.noalias() = g.transpose() * (d - g * u);
  }
  if (outer == max_iterations) res.converged = false;
  return res;
}

// Scratch buffers of nnls_cholesky and least_distance, reused from call to call: a contact
// solve calls them once per stagger, ~30 times a walking step, and their sizes change with
// the step's candidates and the passive set (scratch.h: memory that only grows).
struct NnlsWorkspace {
  ScratchVec u, gtd, z, col, rhs, w, resid, d, r_ldp, y;
  ScratchMat r;
  std::vector<Eigen::Index> set, order;
  std::vector<char> passive;
  // Carried from one solve to the next (nnls_cholesky's `carry`), for a sequence of problems
  // whose G differ in the last row alone (the staggers of one contact step): the last solve's
  // passive set, its Gram factor, and G's last row on the set. The caller clears carry_valid
  // when the other rows change.
  std::vector<Eigen::Index> carry_set;
  ScratchMat carry_r;
  ScratchVec carry_f, carry_x;
  bool carry_valid = false;
  double carry_top_max = 0.0;  // max |G_ij| over the rows but the last (valid with carry_valid)
};

// Lawson-Hanson with the passive set's Gram matrix G_p^T G_p = R^T R kept as an upper
// Cholesky factor that grows by one column per added variable (a triangular solve, O(p^2 + rows
// p)) and shrinks by Givens rotations when variables leave the set (O(p^2)). A column that is
// (numerically) a combination of the passive ones is not added: Lawson-Hanson never needs it,
// and its Gram matrix would be singular. Same iterates as the QR variant, a fraction of the work.
// The solution is left in ws.u, and its residual d - G u in ws.resid; returns false when an
// iteration cap stopped it. `guess` (optional) has n entries. `gt`
// (optional) is G^T kept by the caller (n x rows, column-major): the gradient G^T r, the
// largest cost with hundreds of columns, is then a product over its contiguous columns
// (kernels::cols_times) instead of n short dot products.
//
// `carry`: G's rows but the last are those of the previous call with carry (ws.carry_valid,
// cleared by the caller when they change), so when the guess's support is the previous
// solve's passive set, its Gram factor is carried over and corrected for the new last row
// f by a rank-one update (+ f f^T) and downdate (- f_old f_old^T), O(p^2), instead of being
// formed again column by column, O(rows p^2). (The cross walker's 20-26 passive candidates:
// ~22 k instructions a solve re-forming it, by callgrind.) A downdate that is not
// numerically positive definite falls back to forming it.
inline bool nnls_cholesky(const Eigen::Ref<const Eigen::MatrixXd>& g,
                          const Eigen::Ref<const Eigen::VectorXd>& d, const double* guess,
                          int max_iterations, NnlsWorkspace& ws, const double* gt = nullptr,
                          bool carry = false) {
  const Eigen::Index n = g.cols(), rows = g.rows();
  if (max_iterations <= 0) max_iterations = static_cast<int>(3 * n + 10);
  bool converged = true;
  ScratchVec& u = ws.u;
  u.setZero(n);
  // The rows but the last are the previous carried call's, so their largest entry is too
  // (a pass over all of G per call was ~5 k loads on the cross's 185 candidates).
  const bool top_known = carry && ws.carry_valid && ws.carry_r.rows() == rows;
  const double top_max = top_known   ? ws.carry_top_max
                         : rows > 1 ? g.topRows(rows - 1).cwiseAbs().maxCoeff()
                                    : 0.0;
  const double g_max = std::max(top_max, g.row(rows - 1).cwiseAbs().maxCoeff());
  const double tol = 1e-12 * std::max(1.0, g_max * d.cwiseAbs().maxCoeff());
  // G^T d from d's nonzero rows (a least-distance programme has one: d = e_last), exactly
  // the dense product's value at a fraction of its cost with hundreds of columns.
  ScratchVec& gtd = ws.gtd;
  gtd.setZero(n);
  for (Eigen::Index r = 0; r < rows; ++r)
    if (d[r] != 0.0) gtd.noalias() += d[r] * g.row(r).transpose();
  std::vector<Eigen::Index>& set = ws.set;  // passive variables, in the order of R's columns
  set.clear();
  std::vector<char>& passive = ws.passive;
  passive.assign(n, 0);
  ScratchMat& r = ws.r;  // upper triangular, p x p in use (p <= rows)
  r.resize(rows, rows);
  ScratchVec &z = ws.z, &col = ws.col, &rhs = ws.rhs;
  z.resize(n);
  col.resize(rows);
  rhs.resize(rows);
  // y = R^-T G_p^T d, the forward half of solve(), kept while R only grows: a new column adds
  // one entry to it (O(p), the row the forward substitution would add, in its order, so the
  // same bits), where solving again costs O(p^2) (strided reads of R's rows). Dropping a
  // variable or carrying a factor over invalidates it.
  ScratchVec& y = ws.y;
  y.resize(rows);
  bool y_valid = false;
  auto add = [&](Eigen::Index t) -> bool {
    const Eigen::Index p = static_cast<Eigen::Index>(set.size());
    if (p >= rows) return false;
    for (Eigen::Index c = 0; c < p; ++c) col[c] = g.col(set[c]).dot(g.col(t));
    // (The loops of small_cholesky.h: at p ~ 25, Eigen's blocked triangular solve cost the
    // cross ~2x their instructions.)
    small::upper_transpose_solve(r.data(), p, rows, col.data());
    const double gg = g.col(t).squaredNorm();
    const double rho2 = gg - col.head(p).squaredNorm();
    if (!(rho2 > 1e-12 * gg)) return false;  // dependent on the passive columns
    r.col(p).head(p) = col.head(p);
    r(p, p) = std::sqrt(rho2);
    r.row(p).head(p).setZero();
    if (y_valid) {
      double s = gtd[t];
      for (Eigen::Index c = 0; c < p; ++c) s -= col[c] * y[c];
      y[p] = s / r(p, p);
    }
    set.push_back(t);
    passive[t] = 1;
    return true;
  };
  auto remove_at = [&](Eigen::Index c) {
    // Drop set[c]: delete column c of R, which leaves R upper Hessenberg from column c on, and
    // restore the triangle with Givens rotations on adjacent rows (they keep R^T R, the Gram
    // matrix of the remaining columns). O(p^2), against O(rows p^2) to add the rest again.
    const Eigen::Index p = static_cast<Eigen::Index>(set.size());
    y_valid = false;
    for (Eigen::Index j = c; j + 1 < p; ++j) r.col(j).head(p) = r.col(j + 1).head(p);
    for (Eigen::Index j = c; j + 1 < p; ++j) {
      const double a = r(j, j), b = r(j + 1, j);
      const double rho = std::hypot(a, b);  // > 0: the columns are independent
      const double cs = a / rho, sn = b / rho;
      for (Eigen::Index k = j; k + 1 < p; ++k) {
        const double x = r(j, k), y = r(j + 1, k);
        r(j, k) = cs * x + sn * y;
        r(j + 1, k) = cs * y - sn * x;
      }
    }
    set.erase(set.begin() + c);
  };
  auto rebuild = [&]() {  // drop the variables that left the passive set
    for (Eigen::Index c = static_cast<Eigen::Index>(set.size()) - 1; c >= 0; --c)
      if (!passive[set[c]]) remove_at(c);
  };
  auto solve = [&]() {  // z on the passive set, 0 elsewhere
    const Eigen::Index p = static_cast<Eigen::Index>(set.size());
    if (!y_valid) {
      for (Eigen::Index c = 0; c < p; ++c) y[c] = gtd[set[c]];
      small::upper_transpose_solve(r.data(), p, rows, y.data());
      y_valid = true;
    }
    rhs.head(p) = y.head(p);
    small::upper_solve(r.data(), p, rows, rhs.data());
    z.setZero();
    for (Eigen::Index c = 0; c < p; ++c) z[set[c]] = rhs[c];
  };
  // The previous solve's factor, when the guess's support is its set.
  auto carried = [&]() -> bool {
    if (!carry || !ws.carry_valid || ws.carry_r.rows() != rows || guess == nullptr) return false;
    const Eigen::Index p = static_cast<Eigen::Index>(ws.carry_set.size());
    Eigen::Index support = 0;
    for (Eigen::Index j = 0; j < n; ++j) support += guess[j] > 0.0;
    if (p == 0 || support != p) return false;
    for (Eigen::Index j : ws.carry_set)
      if (!(guess[j] > 0.0)) return false;
    r.topLeftCorner(p, p) = ws.carry_r.topLeftCorner(p, p);
    ScratchVec& x = ws.carry_x;
    x.resize(p);
    for (Eigen::Index c = 0; c < p; ++c) x[c] = g(rows - 1, ws.carry_set[c]);
    small::cholesky_upper_update(r.data(), p, rows, x.data());
    x = ws.carry_f;
    if (!small::cholesky_upper_downdate(r.data(), p, rows, x.data(), 1e-8)) return false;
    set = ws.carry_set;
    for (Eigen::Index j : set) passive[j] = 1;
    return true;
  };
  if (guess != nullptr) {
    if (!carried())
      for (Eigen::Index j = 0; j < n; ++j)
        if (guess[j] > 0.0) add(j);
    for (int it = 0; it < static_cast<int>(n) + 1 && !set.empty(); ++it) {
      solve();
      bool pruned = false;
      for (Eigen::Index j : set)
        if (z[j] <= 0.0) {
          passive[j] = 0;
          pruned = true;
        }
      if (!pruned) {
        u = z;
        break;
      }
      rebuild();
    }
  }
  // w = G^T (d - G u), the NNLS gradient. u is zero outside the passive set (<= rows
  // columns), so G u is formed from those columns alone, in increasing column order (the
  // order of a pass over all n, so the sum is the same to the last bit): with many redundant
  // contact rows (185 on the cross) the dense product cost as much again as G^T r.
  // The entering variable is the largest w_j over the variables not passive and not blocked.
  // Instead of testing two flags per candidate, the passive entries of w are set to -inf
  // here, and a blocked one when it is found (a block lasts until the next gradient), so the
  // selection is a plain arg-max over w (the cross's 185-candidate scans were 10 % of NNLS).
  ScratchVec &w = ws.w, &resid = ws.resid;
  std::vector<Eigen::Index>& order = ws.order;
  w.resize(n);
  resid.resize(rows);
  constexpr double kExcluded = -std::numeric_limits<double>::infinity();
  auto gradient = [&]() {
    resid = d;
    order.assign(set.begin(), set.end());
    std::sort(order.begin(), order.end());
    for (Eigen::Index j : order)
      if (u[j] != 0.0) resid.noalias() -= u[j] * g.col(j);
    if (gt != nullptr) {
      kernels::cols_times(gt, n, rows, resid.data(), w.data());
    } else {
      w.noalias() = g.transpose() * resid;
    }
    for (Eigen::Index j : set) w[j] = kExcluded;
  };
  gradient();
  int outer = 0;
  for (; outer < max_iterations; ++outer) {
    Eigen::Index t = -1;
    double best = tol;
    for (Eigen::Index j = 0; j < n; ++j)
      if (w[j] > best) {
        best = w[j];
        t = j;
      }
    if (t < 0) break;
    if (!add(t)) {
      w[t] = kExcluded;  // blocked: cannot improve the fit beyond the passive columns
      continue;
    }
    int inner = 0;
    for (; inner < max_iterations; ++inner) {
      solve();
      bool all_positive = true;
      for (Eigen::Index j : set)
        if (z[j] <= 0.0) all_positive = false;
      if (all_positive) {
        u = z;
        break;
      }
      double alpha = 1.0;
      for (Eigen::Index j : set)
        if (z[j] <= 0.0) alpha = std::min(alpha, u[j] / (u[j] - z[j]));
      u += alpha * (z - u);
      bool dropped = false;
      // The threshold once per pass, not once per passive variable: the O(n) maximum inside
      // the loop over the set cost the cross (185 candidates) a sixth of its least-distance
      // solves (3.14 -> 2.62 M instructions per step).
      // Zeroing an entry below the threshold cannot change the maximum unless every entry is
      // below it, where the test is moot.
      const double drop_below = 1e-14 * (1.0 + u.cwiseAbs().maxCoeff());
      for (Eigen::Index j : set)
        if (u[j] <= drop_below) {
          u[j] = 0.0;
          passive[j] = 0;
          dropped = true;
        }
      if (dropped) rebuild();
    }
    if (inner == max_iterations) converged = false;
    gradient();  // (which also unblocks: a dropped variable may be useful again)
  }
  if (outer == max_iterations) converged = false;
  if (carry) {
    const Eigen::Index p = static_cast<Eigen::Index>(set.size());
    ws.carry_set = set;
    ws.carry_r.resize(rows, rows);
    ws.carry_r.topLeftCorner(p, p) = r.topLeftCorner(p, p);
    ws.carry_f.resize(p);
    for (Eigen::Index c = 0; c < p; ++c) ws.carry_f[c] = g(rows - 1, set[c]);
    ws.carry_valid = true;
    ws.carry_top_max = top_max;
  }
  return converged;
}

// Least-distance programme: min |x| subject to E x >= f, solved as the NNLS of
// [E^T; f^T] u ~ e_{m+1}. The caller passes g = [E^T; f^T] ((m + 1) x k) so that a constant E
// is copied once. Returns false if infeasible. On success x = E^T lambda with multipliers
// lambda >= 0 (complementary to E x - f). `lambda` must hold k entries (an Eigen::Ref cannot
// resize, and the multipliers are written back into it): on entry they warm-start the active
// set (zeros: no warm start). `converged` is cleared when NNLS stopped at its iteration cap. `ws` is scratch
// (the NNLS solution u is left in ws.u); the Qr variant (the reference) still allocates its
// own. `gt` (optional, Gram variant) is g^T's memory, as for nnls_cholesky. x has m entries.
inline bool least_distance(const Eigen::Ref<const Eigen::MatrixXd>& g,
                           Eigen::Ref<Eigen::VectorXd> x, Eigen::Ref<Eigen::VectorXd> lambda,
                           bool& converged, NnlsSolve how, NnlsWorkspace& ws,
                           const double* gt = nullptr, bool carry = false) {
  const Eigen::Index m = g.rows() - 1;
  ScratchVec& d = ws.d;
  d.setZero(m + 1);
  d[m] = 1.0;
  const double* guess = lambda.data();
  if (how == NnlsSolve::Gram) {
    converged = nnls_cholesky(g, d, guess, 0, ws, gt, carry) && converged;
  } else {
    NnlsResult res = nnls(g, d, guess);
    converged = converged && res.converged;
    ws.u = res.u;
  }
  // r = G u - d. nnls_cholesky leaves d - G u in ws.resid (its last gradient's, formed from
  // the passive columns alone), so the Gram variant skips the product over all k columns.
  ScratchVec& r = ws.r_ldp;
  if (how == NnlsSolve::Gram) {
    r = -ws.resid;
  } else {
    r.noalias() = g * ws.u;
    r -= d;
  }
  if (!(r[m] < -1e-14)) return false;
  x = -r.head(m) / r[m];
  lambda = -ws.u / r[m];
  return true;
}

}  // namespace softrom
