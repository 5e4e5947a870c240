// Small dense non-negative least squares (Lawson & Hanson, "Solving Least Squares Problems",
// 1974, ch. 23) and the least-distance programme it solves (ch. 23.4). Sized for contact
// problems in reduced coordinates: a few dozen rows, a few hundred columns.
#pragma once

#include <Eigen/Dense>
#include <vector>

namespace softrom {

// min |G u - d| subject to u >= 0. Returns u (G.cols()).
//
// `guess` (optional, size G.cols()) warm-starts the passive set with its positive entries:
// the least-squares solution on that set, pruned until positive, is a valid starting point
// for Lawson-Hanson, and a good guess (last solve's support) leaves little to do.
inline Eigen::VectorXd nnls(const Eigen::MatrixXd& g, const Eigen::VectorXd& d,
                            const Eigen::VectorXd* guess = nullptr, int max_iterations = 0) {
  const Eigen::Index n = g.cols();
  if (max_iterations <= 0) max_iterations = static_cast<int>(3 * n + 10);
  Eigen::VectorXd u = Eigen::VectorXd::Zero(n), z(n);
  std::vector<char> passive(n, 0);
  const double tol = 1e-12 * std::max(1.0, g.cwiseAbs().maxCoeff() * d.cwiseAbs().maxCoeff());
  std::vector<Eigen::Index> idx;
  auto solve_passive = [&]() {
    idx.clear();
    for (Eigen::Index j = 0; j < n; ++j)
      if (passive[j]) idx.push_back(j);
    Eigen::MatrixXd gp(g.rows(), static_cast<Eigen::Index>(idx.size()));
    for (size_t c = 0; c < idx.size(); ++c) gp.col(c) = g.col(idx[c]);
    const Eigen::VectorXd zp = gp.colPivHouseholderQr().solve(d);
    z.setZero();
    for (size_t c = 0; c < idx.size(); ++c) z[idx[c]] = zp[c];
  };
  if (guess != nullptr && guess->size() == n) {
    int limit = 0;
    for (Eigen::Index j = 0; j < n; ++j) passive[j] = (*guess)[j] > 0.0 ? 1 : 0;
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
  for (int outer = 0; outer < max_iterations; ++outer) {
    Eigen::Index t = -1;
    double best = tol;
    for (Eigen::Index j = 0; j < n; ++j)
      if (!passive[j] && w[j] > best) {
        best = w[j];
        t = j;
      }
    if (t < 0) break;
    passive[t] = 1;
    for (int inner = 0; inner < max_iterations; ++inner) {
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
    w = g.transpose() * (d - g * u);
  }
  return u;
}

// Least-distance programme: min |x| subject to E x >= f. Returns false if infeasible.
// On success x = E^T lambda with multipliers lambda >= 0 (complementary to E x - f).
// `lambda` on entry (if sized k) warm-starts the active set.
inline bool least_distance(const Eigen::MatrixXd& e, const Eigen::VectorXd& f, Eigen::VectorXd& x,
                           Eigen::VectorXd& lambda) {
  const Eigen::Index m = e.cols(), k = e.rows();
  Eigen::MatrixXd g(m + 1, k);
  g.topRows(m) = e.transpose();
  g.row(m) = f.transpose();
  Eigen::VectorXd d = Eigen::VectorXd::Zero(m + 1);
  d[m] = 1.0;
  const Eigen::VectorXd u = nnls(g, d, lambda.size() == k ? &lambda : nullptr);
  const Eigen::VectorXd r = g * u - d;
  if (!(r[m] < -1e-14)) return false;
  x = -r.head(m) / r[m];
  lambda = -u / r[m];
  return true;
}

}  // namespace softrom
