// Ground contact: staggered projection (the default, Kaufman et al. 2008) and a penalty model.
#include <algorithm>
#include <cmath>
#include <string>

#include "dense_kernels.h"
#include "nnls.h"
#include "reduced_model.h"
#include "scratch.h"
#include "small_cholesky.h"

namespace softrom {

namespace {

// Vector Aitken extrapolation of the stagger map (fast solver only).
//
// Near its fixed point staggering converges linearly, and on the walkers slowly: traced on the
// quadruped, the last staggers of a long step are one sliding foot node whose normal impulse
// creeps up by the same small amount every stagger (its friction shifts load onto it, which
// raises its friction), a contraction rate of 0.9-0.99. When the loaded set has held for
// three staggers and two successive changes of the impulses d_k, d_(k-1) point the same way
// (cosine > 0.9), the sequence is taken as geometric with ratio r = d_k.d_(k-1) / |d_(k-1)|^2
// and, if it is slow (0.5 <= r < 1), the friction impulses jump towards its limit,
// lambda_t += min(r / (1 - r), 10) d_k,t (the next normal solve answers the jump; the friction
// half-step after it puts lambda_t back inside the Coulomb discs, so they are not projected
// here: clipping the jump to the current discs undid it for the sliding nodes it is for). The
// fixed point is staggering's own: a step is declared converged only on two plain staggers
// after the last jump, by the same test, and no jump is made in the last staggers before the
// cap. A step makes at most kMaxJumps jumps: unlimited, the jumps can drive staggering round
// a cycle that never settles (a jump shifts load between the nodes of a foot, staggering
// creeps back, the next jump shifts it again). On four open-loop tripod gaits with the cap
// raised to 400, 11.4 % of the steps never converged; with at most 5 jumps 1.1 %, with none
// 0.6 %. Measured in benchmarks/PROFILE.md (2026-12-03, Aitken entry and the entry on its
// jump limit).
class StaggerExtrapolation {
 public:
  // A step's start, from its first impulses.
  void reset(const ScratchVec& lam_n, const ScratchVec& lam_t) {
    k_ = lam_n.size();
    last_.resize(3 * k_);
    d_.resize(3 * k_);
    d_prev_.resize(3 * k_);
    last_ << lam_n, lam_t;
    loaded_.clear();
    held_ = 0;
    jumps_ = 0;
    have_d_ = false;
  }

  // The impulses at the end of a stagger; returns the factor f of the jump
  // lambda_t += f (lambda_t - lambda_t,prev), 0 for none.
  double observe(const ScratchVec& lam_n, const ScratchVec& lam_t, const std::vector<int>& loaded) {
    if (loaded == loaded_) {
      ++held_;
    } else {
      held_ = 0;
      loaded_ = loaded;
    }
    d_prev_.swap(d_);
    d_.head(k_) = lam_n - last_.head(k_);
    d_.tail(2 * k_) = lam_t - last_.tail(2 * k_);
    last_.head(k_) = lam_n;
    last_.tail(2 * k_) = lam_t;
    const bool have_pair = have_d_;
    have_d_ = true;
    if (!have_pair || held_ < kHold || jumps_ >= kMaxJumps) return 0.0;
    const double dd = d_prev_.squaredNorm(), cross = d_.dot(d_prev_);
    if (!(dd > 0.0) || !(cross > 0.0)) return 0.0;
    const double r = cross / dd;
    if (r >= 1.0 || r < kMinRatio || cross < kMinCosine * std::sqrt(dd * d_.squaredNorm()))
      return 0.0;
    return std::min(r / (1.0 - r), kMaxFactor);
  }

  // After a jump: lambda_t moved by f d_t, and the history starts again.
  void jumped(const ScratchVec& lam_t) {
    ++jumps_;
    last_.tail(2 * k_) = lam_t;
    have_d_ = false;
    held_ = 0;
    loaded_.clear();
  }

  auto friction_change() const { return d_.tail(2 * k_); }

 private:
  static constexpr int kHold = 2;  // the loaded set unchanged over the last two staggers
  static constexpr double kMinCosine = 0.9;
  static constexpr double kMinRatio = 0.5;  // faster sequences converge without help
  static constexpr double kMaxFactor = 10.0;
  static constexpr int kMaxJumps = 5;  // per step (the plateau of 4-6 measured on the tripod)
  Eigen::Index k_ = 0;
  ScratchVec last_, d_, d_prev_;  // (lambda_n, lambda_t): the last impulses and their changes
  std::vector<int> loaded_;
  int held_ = 0, jumps_ = 0;
  bool have_d_ = false;
};

// The loaded nodes' rows in the metric of the step (fast solver only), for the staggers in
// which the loaded set W holds (85-90 % of the staggers after the first on the quadruped,
// tripod and beam). On such a stagger both halves are small dense problems over W's 3 n
// impulses, and the velocity is formed once from them: v = v_free + L^-T Y lambda_W with
//   Y = L^-1 [J_n,W^T  J_t,W^T]   (M + 6 x 3 n; the normal columns are columns of E^T),
//   D = Y^T Y = J_W A^-1 J_W^T    (W's Delassus matrix),   c = J_W v_free.
// Such a stagger skips NNLS over every candidate and four of the six (M + 6) triangular
// solves, and factors nothing but the friction half's 2 n x 2 n system. callgrind_step.py (100
// random steps), instructions per stagger: quadruped 120 k -> 93 k, tripod 119 k -> 84 k, beam
// 99 k -> 77 k (benchmarks/PROFILE.md, session 12).
struct LoadedRows {
  std::vector<int> set;       // the loaded candidates, in the order of Y's columns
  std::vector<char> member;   // per candidate: in the set
  ScratchMat y, d;
  ScratchVec c;
  ScratchMat d_nn;            // the Cholesky factor of D's normal block, once per set
  bool normal_ok = false;     // W's normal rows independent (D_nn positive definite)

  // A step's start (k candidates): no set.
  void reset(int k) {
    set.clear();
    member.assign(k, 0);
    normal_ok = false;
  }
};

// Newton's method on staggering's fixed point over a held loaded set W of n nodes (fast solver
// only), taken where the Aitken jump above would be: the set has held and the staggers creep.
// With the normal half exact on W (LoadedRows), the normal impulses and the loaded nodes'
// tangential velocities are affine in W's friction impulses lambda (2 n):
//   lambda_n = a0 + N lambda,   a0 = D_nn^-1 (b_W - c_n),   N = -D_nn^-1 D_nt,
//   u = u0 + T lambda,          u0 = c_t + D_tn a0,          T = D_tt + D_tn N,
// and the fixed point of the smoothed law lambda_l = -r_l u_l / s_l (r = mu lambda_n,
// s_l = sqrt(|u_l|^2 + eps^2)) is the root of F_l = r_l u_l + s_l lambda_l. Newton on the
// law in that form, with s_l an unknown (F2_l = s_l^2 - |u_l|^2 - eps^2) eliminated from the
// step (ds_l = (-F2_l + 2 u_l^T T_l dlambda) / (2 s_l)), solves
//   [(r_l I + lambda_l u_l^T / s_l) T_l + mu u_l N_l + s_l E_l] dlambda
//       = -F_l + lambda_l F2_l / (2 s_l)
// (T_l, N_l: node l's rows; E_l picks lambda_l), whose F2 term is zero here: s is reset to
// sqrt(|u|^2 + eps^2) after every step, so F2 = 0 at every iterate. Unlike Newton on
// lambda_l + r_l u_l / s_l, whose derivative mu lambda_n / eps at a sticking node confines its
// steps to ~eps (measured: it hovered there, benchmarks/PROFILE.md, the coupled Newton entry
// of 2026-12-03), this primal-dual form keeps lambda free of the law until the root, so a node
// crossing the stick-slip boundary costs an iteration or two. A try fails, and staggering goes
// on as before, when a step would take a node's load to zero or below (the answer needs
// another set: staggering's normal half finds it) or after kMaxIterations. The answer is
// staggering's own fixed point: the stagger after it must reproduce its velocity to the
// contact tolerance before the step ends (benchmarks/PROFILE.md, session 22).
class HeldSetNewton {
 public:
  // lam: W's friction impulses, node by node in the set's order (in: staggering's last; out:
  // the root). d, c: W's Delassus matrix and free contact velocities (LoadedRows), d_nn_factor
  // D_nn's Cholesky factor, b_w W's normal bounds.
  bool solve(const ScratchMat& d, const ScratchVec& c, const ScratchMat& d_nn_factor,
             const ScratchVec& b_w, double mu, double eps, double tol, ScratchVec& lam) {
    const Eigen::Index n = b_w.size(), n2 = 2 * n;
    a0_ = b_w - c.head(n);
    small::cholesky_upper_solve(d_nn_factor.data(), n, n, a0_.data());
    nm_ = -d.block(0, n, n, n2);
    for (Eigen::Index j = 0; j < n2; ++j)
      small::cholesky_upper_solve(d_nn_factor.data(), n, n, nm_.col(j).data());
    t_ = d.bottomRightCorner(n2, n2);
    t_.noalias() += d.block(n, 0, n2, n) * nm_;
    u_ = c.tail(n2);
    u_.noalias() += d.block(n, 0, n2, n) * a0_;
    u_.noalias() += t_ * lam;
    r_ = a0_;
    r_.noalias() += nm_ * lam;
    r_ *= mu;
    s_.resize(n);
    for (Eigen::Index l = 0; l < n; ++l)
      s_[l] = std::sqrt(u_.segment<2>(2 * l).squaredNorm() + eps * eps);
    jac_.resize(n2, n2);
    step_.resize(n2);
    for (int it = 0; it < kMaxIterations; ++it) {
      iterations_ = it;
      if (!(r_.array() > 0.0).all()) return fail('r');
      for (Eigen::Index l = 0; l < n; ++l) {
        const double u0 = u_[2 * l], u1 = u_[2 * l + 1], l0 = lam[2 * l], l1 = lam[2 * l + 1];
        step_[2 * l] = -(r_[l] * u0 + s_[l] * l0);
        step_[2 * l + 1] = -(r_[l] * u1 + s_[l] * l1);
        const double is = 1.0 / s_[l];
        const double p00 = r_[l] + l0 * u0 * is, p01 = l0 * u1 * is;
        const double p10 = l1 * u0 * is, p11 = r_[l] + l1 * u1 * is;
        const double m0 = mu * u0, m1 = mu * u1;
        for (Eigen::Index j = 0; j < n2; ++j) {
          const double t0 = t_(2 * l, j), t1 = t_(2 * l + 1, j), nj = nm_(l, j);
          jac_(2 * l, j) = p00 * t0 + p01 * t1 + m0 * nj;
          jac_(2 * l + 1, j) = p10 * t0 + p11 * t1 + m1 * nj;
        }
        jac_(2 * l, 2 * l) += s_[l];
        jac_(2 * l + 1, 2 * l + 1) += s_[l];
      }
      if (!small::lu_solve(jac_.data(), n2, step_.data()) || !step_.allFinite())
        return fail('s');
      du_.noalias() = t_ * step_;
      dr_.noalias() = nm_ * step_;
      dr_ *= mu;
      for (Eigen::Index l = 0; l < n; ++l)
        if (r_[l] + dr_[l] <= 0.0) return fail('l');  // a node leaves W
      lam += step_;
      u_ += du_;
      r_ += dr_;
      for (Eigen::Index l = 0; l < n; ++l)
        s_[l] = std::sqrt(u_.segment<2>(2 * l).squaredNorm() + eps * eps);
      // (Quadratic near the root: the next stagger's change is then far below tol.)
      if (du_.cwiseAbs().maxCoeff() < 0.1 * tol) {
        iterations_ = it + 1;
        failure_ = 0;
        return true;
      }
    }
    iterations_ = kMaxIterations;
    return fail('c');
  }

  // The last solve's Newton steps taken, and why it failed ('l': a node would leave W, 'r': a
  // load was not positive, 's': a singular step, 'c': the iteration cap; 0 after a root), for
  // the stagger trace.
  int iterations() const { return iterations_; }
  char failure() const { return failure_; }

  // The normal impulses lambda_n = a0 + N lambda of the last solve's set, into out (n).
  template <class Out>
  void normal_impulses(const ScratchVec& lam, Out&& out) const {
    out = a0_;
    out.noalias() += nm_ * lam;
  }

 private:
  // Measured on the walkers' tries (session 22): roots are reached in 2-8 iterations, most in 3-5.
  static constexpr int kMaxIterations = 8;
  bool fail(char why) {
    failure_ = why;
    return false;
  }
  int iterations_ = 0;
  char failure_ = 0;
  ScratchMat nm_, t_, jac_;
  ScratchVec a0_, u_, r_, s_, step_, du_, dr_;
};

}  // namespace

// Everything a contact step works in, kept by the worker's Workspace from step to step, so a
// step allocates nothing once the worker has seen its largest sizes (scratch.h). The names are
// solve_contacts' (below), where each is explained.
struct ContactScratch {
  std::vector<int> active, loaded, jt_l_set, pool_slot;
  std::vector<char> traced;  // with config.profile: loaded at the last traced stagger
  std::vector<double> gap;
  std::vector<Eigen::Index> slots;
  ScratchVec old, b, lam_n, lam_t, v_free, solve_tmp, response, x_ldp, lam_ldp, row_gap, vc_prev,
      vc, weight, v_prev, dv_stagger, v_second, ut_l, rhs_l, lam_w, v_on, pool_c, tangent_row,
      lam_held, b_held;
  ScratchMat jn, jt, g, gt, et_rows, l_inv, l_inv_t, hess, wjt, jt_l, dual_sys, pool_y, pool_gram,
      gram;
  ScratchRowMat y_rows;
  LoadedRows rows;
  StaggerExtrapolation extrapolation;
  HeldSetNewton held_newton;
};

Workspace::Workspace() = default;
Workspace::~Workspace() = default;

// Staggered projection (Kaufman, Sueda, James & Pai 2008) in reduced coordinates.
//
// With A the Newton matrix of the step and v* the contact-free velocity, the post-contact
// velocity minimises 1/2 |v - v*|_A^2 under the per-node conditions of the paper's
// Eq. (LCPConstraint). Staggering alternates two convex problems until the velocities of the
// contact nodes stop changing:
//
//   normal:   min 1/2 |v - v'|_A^2          s.t. J_n,i v >= b_i                (friction held)
//   friction: min 1/2 |v - v''|_A^2 + sum_i mu lambda_n,i |J_t,i v|        (normals held)
//
// with b_i = -z_i / dt for a node above the plane (it may not cross it this step) and
// b_i = -beta z_i / dt for a penetrating one (Baumgarte: a fraction beta of the penetration is
// removed per step, instead of a velocity kick that ejects it in one step).
//
// Both are solved in the primal, over the M + 6 reduced velocities, not over the 3k contact
// impulses: k contact rows of rank <= M + 6 make the impulses non-unique (Delassus matrices
// with condition numbers ~1e6), so Gauss-Seidel on impulses crawls, while the primal problems
// are strongly convex and small. The normal problem is solved exactly as a least-distance
// programme, the friction problem (maximal dissipation) by a reweighted least-squares step on
// |J_t,i v|_eps = sqrt(|J_t,i v|^2 + eps^2). Every step ends with a normal solve, so the normal
// constraints hold even when staggering stops at its cap (reported in info). In the fast
// solver, a stagger whose loaded set is the last one's (most of them) runs both halves over
// that set's impulses (LoadedRows), falling back to NNLS when a node leaves or joins.
int ReducedModel::solve_contacts(const ReducedConfig& cfg, const VecX& q, const MatX& a,
                                 const Eigen::LLT<MatX>& a_llt, VecX& v, VecX& impulses,
                                 Workspace& ws, StepInfo& info) const {
  const double h = cfg.dt;
  const double mu = cfg.friction;
  const double tol = cfg.contact_tolerance;
  const int ns = static_cast<int>(surface_nodes_.size());
  const Eigen::Index m = basis_cols_;
  // The fast solver's variants below (the reference keeps the original arithmetic).
  const bool fast = cfg.solver == Solver::Fast;
  const NnlsSolve how = fast ? NnlsSolve::Gram : NnlsSolve::Qr;
  // Candidate rows: every surface node on or near the ground, or heading there this step.
  if (!ws.ground_rows_ready) {  // near_ground has not formed them for this q and v
    ws.ground_z.noalias() = normal_rows_ * q;
    ws.ground_vn.noalias() = normal_rows_ * v;
  }
  ws.ground_rows_ready = false;
  const VecX& z_all = ws.ground_z;
  const VecX& vn_all = ws.ground_vn;
  if (!ws.contact) ws.contact = std::make_unique<ContactScratch>();
  ContactScratch& sc = *ws.contact;
  std::vector<int>& active = sc.active;
  std::vector<double>& gap = sc.gap;
  active.clear();
  gap.clear();
  for (int c = 0; c < ns; ++c) {
    const double z = surface_rest_[3 * c + 2] + z_all[c] - cfg.ground_height;
    if (z + 2.0 * h * std::min(vn_all[c], 0.0) < cfg.contact_margin) {
      active.push_back(c);
      gap.push_back(z);
    }
  }
  const int k = static_cast<int>(active.size());
  info.active_rows = k;
  if (k == 0) {
    impulses.setZero();
    return 0;
  }
  ScratchVec& old = sc.old;
  old = impulses;
  impulses.setZero();

  ScratchMat &jn = sc.jn, &jt = sc.jt;
  ScratchVec &b = sc.b, &lam_n = sc.lam_n, &lam_t = sc.lam_t;
  jn.resize(k, m);
  jt.resize(2 * k, m);
  b.resize(k);
  lam_n.resize(k);
  lam_t.resize(2 * k);
  for (int i = 0; i < k; ++i) {
    const int c = active[i];
    jn.row(i) = surface_rows_.row(3 * c + 2);
    jt.row(2 * i) = surface_rows_.row(3 * c);
    jt.row(2 * i + 1) = surface_rows_.row(3 * c + 1);
    b[i] = gap[i] >= 0.0 ? -gap[i] / h : -cfg.stabilization * gap[i] / h;
    lam_n[i] = std::max(old[3 * c + 2], 0.0);  // warm start by node id
    lam_t.segment<2>(2 * i) = old.segment<2>(3 * c);
  }
  // out = A x for a column-major A (J_n, Y): the fast solver's kernel, Eigen's in the reference.
  auto times = [fast](const auto& a, const auto& x, ScratchVec& out) {
    if (fast) {
      out.resize(a.rows());
      kernels::cols_times(a.data(), a.rows(), a.cols(), x.data(), out.data());
    } else {
      out.noalias() = a * x;
    }
  };
  ScratchVec& v_free = sc.v_free;
  v_free = v;
  const double eps = tol;  // smoothing of |v_t|: sticking nodes creep at most ~eps
  ws.nnls.carry_valid = false;  // E changes with the step: no factor carries over into it
  // Constant within the step: E^T = L^-1 J_n^T (the LDP's constraint matrix). The velocity
  // response to the impulses, A^-1 J^T lambda, is two triangular solves per stagger: forming
  // A^-1 J_n^T and A^-1 J_t^T once instead takes 3k right-hand sides (k candidates; ~130k
  // multiply-adds on the quadruped) for per-stagger products no cheaper than the solves.
  ScratchMat& g = sc.g;
  g.resize(m + 1, k);
  // The fast solver's g^T = [E  b - J_n v'] (k x m + 1), for NNLS's gradient.
  ScratchMat& gt = sc.gt;
  if (fast) {
    // jn's column-major memory is J_n^T row by row: solve in a copy, then transpose into g.
    // The copy, read as a column-major k x m matrix, is E = J_n L^-T itself.
    ScratchMat& et_rows = sc.et_rows;
    et_rows = jn;
    kernels::lower_solve_rows(a_llt.matrixLLT().data(), m, et_rows.data(), k);
    g.topRows(m) = Eigen::Map<const RowMatX>(et_rows.data(), m, k);
    gt.resize(k, m + 1);
    gt.leftCols(m) = et_rows;
  } else {
    g.topRows(m) = a_llt.matrixL().solve(jn.transpose());
  }
  // x <- L^-T x with A = L L^T. The fast solver applies L^-1 and L^-T as products with
  // explicit inverses, formed once per step (L^-1's rows by the row-oriented substitution,
  // an (M + 6)^3 / 6 sum; the ~50 solves of a quadruped step each become a vectorised
  // product); the reference solves by substitution.
  ScratchMat &l_inv = sc.l_inv, &l_inv_t = sc.l_inv_t;
  ScratchVec& solve_tmp = sc.solve_tmp;
  solve_tmp.resize(m);
  if (fast) {
    l_inv_t.setIdentity(m, m);  // row-major L^-1 is column-major L^-T
    kernels::lower_solve_rows(a_llt.matrixLLT().data(), m, l_inv_t.data(), m);
    l_inv = l_inv_t.transpose();
  }
  auto upper_solve = [&](ScratchVec& x) {
    if (fast) {
      kernels::cols_times(l_inv_t.data(), m, m, x.data(), solve_tmp.data());
      x = solve_tmp;
    } else {
      a_llt.matrixU().solveInPlace(x);
    }
  };
  // J_t,i x for candidate i (its two tangent rows): a loop over J_t's column-major memory in
  // the fast solver (Eigen's general matrix-vector product costs more to set up than the 2 M
  // multiply-adds), Eigen's product in the reference.
  auto tangent = [&](int i, const auto& x) -> Eigen::Vector2d {
    if (!fast) return jt.middleRows(2 * i, 2) * x;
    const double* p = jt.data() + 2 * i;
    const Eigen::Index ld = jt.rows();
    double s0 = 0.0, s1 = 0.0;
    for (Eigen::Index r = 0; r < m; ++r) {
      s0 += p[r * ld] * x[r];
      s1 += p[r * ld + 1] * x[r];
    }
    return {s0, s1};
  };
  ScratchVec& response = sc.response;
  response.resize(m);
  auto velocity_after = [&](const ScratchMat& j, const ScratchVec& lam) -> const ScratchVec& {
    if (fast) {
      // Only loaded nodes carry impulses (~7 of 64 candidates on a walker): J^T lambda from
      // their rows, not a product over every row.
      response.setZero();
      for (Eigen::Index i = 0; i < lam.size(); ++i)
        if (lam[i] != 0.0) response.noalias() += lam[i] * j.row(i).transpose();
    } else {
      response.noalias() = j.transpose() * lam;
    }
    if (fast) {
      kernels::cols_times(l_inv.data(), m, m, response.data(), solve_tmp.data());
      kernels::cols_times(l_inv_t.data(), m, m, solve_tmp.data(), response.data());
    } else {
      a_llt.solveInPlace(response);
    }
    response += v_free;
    return response;
  };

  // Per-stagger buffers (row_gap: a J_n product).
  ScratchVec &x_ldp = sc.x_ldp, &lam_ldp = sc.lam_ldp, &row_gap = sc.row_gap;
  x_ldp.resize(m);
  lam_ldp.resize(k);
  row_gap.resize(k);
  auto normal_solve = [&](const ScratchVec& v_prime) {
    // With A = L L^T and x = L^T (v - v'), the normal problem is the least-distance programme
    // min |x| s.t. J_n L^-T x >= b - J_n v', solved exactly by NNLS (Lawson & Hanson), whose
    // active set copes with the redundant rows; the multipliers are the normal impulses.
    ++info.normal_iterations;
    ScopedTimer timer(cfg.profile ? &info.time_normal : nullptr);
    times(jn, v_prime, row_gap);
    g.row(m) = (b - row_gap).transpose();
    if (fast) gt.col(m) = g.row(m).transpose();
    lam_ldp = lam_n;  // warm start: last stagger's (or step's) loaded nodes
    bool nnls_ok = true;
    if (least_distance(g, x_ldp, lam_ldp, nnls_ok, how, ws.nnls, fast ? gt.data() : nullptr,
                       fast)) {
      upper_solve(x_ldp);
      v = v_prime + x_ldp;
      lam_n = lam_ldp;
    } else {
      v = v_prime;  // unreachable for a ground plane (moving up is always feasible)
      lam_n.setZero();
      nnls_ok = false;
    }
    // The LDP's answer must be feasible: every candidate ends on or above its bound.
    if (nnls_ok) {
      times(jn, v, row_gap);
      const double worst = (b - row_gap).maxCoeff();
      if (worst > tol) nnls_ok = false;
    }
    if (!nnls_ok) info.contact_converged = false;
  };

  ScratchVec &vc_prev = sc.vc_prev, &vc = sc.vc, &weight = sc.weight, &v_prev = sc.v_prev,
             &dv_stagger = sc.dv_stagger, &v_second = sc.v_second;
  weight.resize(k);
  v_prev = v;
  dv_stagger.resize(m);
  v_second.resize(m);
  Eigen::Vector2d ut2;
  auto contact_velocities = [&](ScratchVec& out) {
    out.head(k).noalias() = jn * v;
    out.tail(2 * k).noalias() = jt * v;
  };
  if (!fast) {  // the reference compares all 3k contact velocities stagger to stagger
    vc_prev.resize(3 * k);
    vc.resize(3 * k);
    contact_velocities(vc_prev);
  }
  ScratchMat &hess = sc.hess, &wjt = sc.wjt;
  hess.resize(m, m);
  wjt.resize(2 * k, m);
  std::vector<int>& loaded = sc.loaded;
  loaded.clear();
  // The loaded nodes' tangent rows J_t,l (2 nl x M + 6, column-major), gathered when the loaded
  // set changes, so that their tangential velocities are one product (fast solver).
  ScratchMat& jt_l = sc.jt_l;
  std::vector<int>& jt_l_set = sc.jt_l_set;
  jt_l.resize(0, m);
  jt_l_set.clear();
  ScratchVec& ut_l = sc.ut_l;
  auto loaded_tangents = [&](const auto& x) -> const ScratchVec& {
    if (jt_l_set != loaded) {
      jt_l.resize(2 * static_cast<Eigen::Index>(loaded.size()), m);
      for (size_t l = 0; l < loaded.size(); ++l)
        jt_l.middleRows(2 * l, 2) = jt.middleRows(2 * loaded[l], 2);
      jt_l_set = loaded;
    }
    times(jt_l, x, ut_l);
    return ut_l;
  };
  ScratchMat& dual_sys = sc.dual_sys;
  ScratchVec &rhs_l = sc.rhs_l, &lam_w = sc.lam_w, &v_on = sc.v_on;
  v_on.resize(m);
  LoadedRows& rows = sc.rows;
  rows.reset(k);
  // Every candidate that has been in a loaded set during this step (the pool, ~10 on a
  // quadruped step) keeps its three columns of Y = L^-1 [J_n,i^T  J_t,i^T], their products
  // with every other pool column (the pool's Gram matrix) and c_i = J_i v_free, so that a new
  // loaded set (~5 per quadruped step) gathers its D and c instead of forming them: only a
  // candidate's first entry costs a triangular solve and its columns' products with the pool.
  // (The pool's memory is the worker's: its capacity may be a former step's.)
  std::vector<int>& pool_slot = sc.pool_slot;
  pool_slot.assign(k, -1);
  int pool_size = 0;
  ScratchMat &pool_y = sc.pool_y, &pool_gram = sc.pool_gram;
  ScratchVec& pool_c = sc.pool_c;
  pool_y.resize(m, 0);  // empty, as the pool starts each step (the memory stays)
  pool_gram.resize(0, 0);
  pool_c.resize(0);
  ScratchRowMat& y_rows = sc.y_rows;  // (y_rows, gram: the primal friction system's buffers)
  ScratchVec& tangent_row = sc.tangent_row;
  tangent_row.resize(m);
  ScratchMat& gram = sc.gram;
  std::vector<Eigen::Index>& slots = sc.slots;
  auto enter_pool = [&](const std::vector<int>& set) {
    int fresh = 0;
    for (int i : set) fresh += pool_slot[i] < 0;
    if (fresh == 0) return;
    const int old = pool_size, total = old + fresh;
    if (pool_y.cols() < 3 * total) {  // grow, keeping the columns and products formed so far
      const Eigen::Index cap =
          std::min<Eigen::Index>(3 * k, std::max<Eigen::Index>(3 * total + 12, 2 * pool_y.cols()));
      pool_y.conservative_resize(m, cap);
      pool_gram.conservative_resize(cap, cap);
      pool_c.conservative_resize(cap, 1);
    }
    // The new candidates' L^-1 J_t,i^T as products with L^-1 (formed once per step): one or two
    // candidates enter at a time, too few right-hand sides for the row-wise substitution to
    // vectorise (~13 k instructions an entry on the quadruped, by callgrind).
    int f = 0;
    for (int i : set)
      if (pool_slot[i] < 0) pool_slot[i] = old + f++;
    for (int i : set) {
      const int p = pool_slot[i];
      if (p < old) continue;
      pool_y.col(3 * p) = g.col(i).head(m);
      for (int t = 0; t < 2; ++t) {
        tangent_row = jt.row(2 * i + t).transpose();
        kernels::cols_times(l_inv.data(), m, m, tangent_row.data(),
                            pool_y.col(3 * p + 1 + t).data());
      }
      pool_c[3 * p] = jn.row(i).dot(v_free);
      pool_c.segment<2>(3 * p + 1) = tangent(i, v_free);
    }
    // The new columns against every pool column (the new ones included), then the mirror.
    pool_gram.block(0, 3 * old, 3 * total, 3 * fresh).noalias() =
        pool_y.leftCols(3 * total).transpose() * pool_y.middleCols(3 * old, 3 * fresh);
    pool_gram.block(3 * old, 0, 3 * fresh, 3 * old) =
        pool_gram.block(0, 3 * old, 3 * old, 3 * fresh).transpose();
    pool_size = total;
  };
  auto build_rows = [&](const std::vector<int>& set) {
    const int nw = static_cast<int>(set.size());
    for (int i : rows.set) rows.member[i] = 0;
    rows.set = set;
    for (int i : set) rows.member[i] = 1;
    enter_pool(set);
    // Y's columns: the normals of W, then each node's two tangents; D and c gathered alike.
    slots.resize(3 * nw);
    for (int l = 0; l < nw; ++l) {
      const Eigen::Index p = pool_slot[set[l]];
      slots[l] = 3 * p;
      slots[nw + 2 * l] = 3 * p + 1;
      slots[nw + 2 * l + 1] = 3 * p + 2;
    }
    rows.y.resize(m, 3 * nw);
    rows.c.resize(3 * nw);
    rows.d.resize(3 * nw, 3 * nw);
    for (int a = 0; a < 3 * nw; ++a) {
      rows.y.col(a) = pool_y.col(slots[a]);
      rows.c[a] = pool_c[slots[a]];
    }
    for (int b = 0; b < 3 * nw; ++b)
      for (int a = 0; a < 3 * nw; ++a) rows.d(a, b) = pool_gram(slots[a], slots[b]);
    rows.d_nn = rows.d.topLeftCorner(nw, nw);
    rows.normal_ok = small::cholesky_upper(rows.d_nn.data(), nw, nw);
  };
  // The normal half on the last stagger's loaded set W: J_n,W v = b_W with the friction
  // impulses held, i.e. D_nn lambda_n = b_W - c_n - D_nt lambda_t. It is the least-distance
  // programme's answer (the same velocity as NNLS, to round-off) when lambda_n > 0 and every
  // other candidate ends on or above its bound; otherwise (a node leaves or joins) it returns
  // false and NNLS runs. The bound is met to within kSlack (1e-5 of the default contact
  // tolerance; NNLS adds a violated candidate at a similar level).
  constexpr double kSlack = 1e-9;
  auto normal_on_loaded_set = [&]() -> bool {
    const int nw = static_cast<int>(rows.set.size());
    if (nw == 0 || !rows.normal_ok || loaded != rows.set) return false;
    for (int i = 0; i < k; ++i)  // friction off W (a jump's) would not be held
      if (!rows.member[i] && (lam_t[2 * i] != 0.0 || lam_t[2 * i + 1] != 0.0)) return false;
    ScopedTimer timer(cfg.profile ? &info.time_normal : nullptr);
    lam_w.resize(3 * nw);
    rhs_l.resize(nw);
    for (int l = 0; l < nw; ++l) {
      lam_w.segment<2>(nw + 2 * l) = lam_t.segment<2>(2 * rows.set[l]);
      rhs_l[l] = b[rows.set[l]] - rows.c[l];
    }
    rhs_l.noalias() -= rows.d.block(0, nw, nw, 2 * nw) * lam_w.tail(2 * nw);
    small::cholesky_upper_solve(rows.d_nn.data(), nw, nw, rhs_l.data());
    if (!(rhs_l.array() > 0.0).all()) return false;
    lam_w.head(nw) = rhs_l;
    times(rows.y, lam_w, v_on);
    upper_solve(v_on);
    v_on += v_free;
    times(jn, v_on, row_gap);
    for (int i = 0; i < k; ++i)
      if (!rows.member[i] && b[i] - row_gap[i] > kSlack) return false;
    v = v_on;
    lam_n.setZero();
    for (int l = 0; l < nw; ++l) lam_n[rows.set[l]] = rhs_l[l];
    ++info.normal_iterations;
    return true;
  };
  // With config.profile, the stagger loop's course in info.stagger_trace (StepInfo's grammar).
  const bool trace = cfg.profile;
  std::vector<char>& traced = sc.traced;
  if (trace) {
    traced.resize(k);
    for (int i = 0; i < k; ++i) traced[i] = lam_n[i] > 0.0;  // the warm start's loaded set
  }
  auto trace_normal = [&](bool on_set) {
    int n = 0, entered = 0, left = 0;
    for (int i = 0; i < k; ++i) {
      const char now = lam_n[i] > 0.0;
      n += now;
      entered += now && !traced[i];
      left += !now && traced[i];
      traced[i] = now;
    }
    std::string& t = info.stagger_trace;
    t += on_set ? 'S' : 'N';
    t += std::to_string(n);
    if (entered > 0 || left > 0)
      t += "(+" + std::to_string(entered) + "-" + std::to_string(left) + ")";
    t += ' ';
  };
  int stagger = 0;
  bool converged = false;
  StaggerExtrapolation& extrapolation = sc.extrapolation;
  extrapolation.reset(lam_n, lam_t);
  bool after_jump = false;  // the stagger after a jump may not declare convergence
  constexpr int kMaxNewtonTries = 3;
  int newton_tries = 0;
  HeldSetNewton& held_newton = sc.held_newton;
  for (; stagger < cfg.max_stagger_iterations; ++stagger) {
    // --- Normal problem with the friction impulses held fixed.
    const bool on_set = fast && normal_on_loaded_set();
    if (!on_set) normal_solve(velocity_after(jt, lam_t));
    if (trace) trace_normal(on_set);
    // --- Friction problem with the normal impulses held fixed.
    if (!on_set) v_second = velocity_after(jn, lam_n);
    ++info.friction_iterations;
    ScopedTimer timer(cfg.profile ? &info.time_friction : nullptr);
    {
      // One reweighted least-squares step on the smoothed, strictly convex
      //   phi(v) = 1/2 |v - v''|_A^2 + sum_i c_i sqrt(|J_t,i v|^2 + eps^2),  c_i = mu lambda_n,i:
      // v minimises phi's quadratic majoriser at the current velocities, so phi decreases and
      // the friction impulses -c_i J_t,i v / |J_t,i v|_eps stay inside the Coulomb discs. The
      // stagger loop iterates to the joint fixed point. (Measured on the quadruped: staggering
      // converges linearly at a rate near 0.95 per stagger; solving this half to convergence
      // by Newton's method made it oscillate instead: the slow part is the normal-friction
      // coupling, a sliding node's load creeping up stagger by stagger, which Newton on the
      // held set's fixed point (HeldSetNewton) or else the guarded Aitken jump shortens.
      // Anderson acceleration of the stagger map on the loaded friction impulses, restarted
      // when the loaded set changes or the residual grows, took 1-22 % fewer staggers than
      // the Aitken jump but stopped further from the converged step on three of eight gait
      // and random rows, and saved 1-4 % of a step's instructions: benchmarks/PROFILE.md,
      // session 21.)
      // Only loaded nodes (lambda_n > 0) carry friction: the others have zero weight.
      loaded.clear();
      for (int i = 0; i < k; ++i)
        if (lam_n[i] > 0.0 && mu > 0.0) loaded.push_back(i);
      const int nl = static_cast<int>(loaded.size());
      lam_t.setZero();
      if (nl == 0) {
        v = v_second;
      } else {
        const ScratchVec* ut_fast = fast ? &loaded_tangents(v) : nullptr;
        for (int l = 0; l < nl; ++l) {
          const int i = loaded[l];
          const Eigen::Vector2d ut =
              fast ? Eigen::Vector2d(ut_fast->segment<2>(2 * l)) : tangent(i, v);
          weight[l] = mu * lam_n[i] / std::sqrt(ut.squaredNorm() + eps * eps);
        }
        // The step solves (A + J_l^T W J_l) v = A v'' (J_l: the loaded nodes' tangent rows,
        // W their weights). With fewer rows than coordinates (2 nl < M + 6: a walker stands
        // on ~7 nodes) it is solved in the rows' space instead (Woodbury):
        //   v = v'' - A^-1 J_l^T (W^-1 + J_l A^-1 J_l^T)^-1 J_l v'',
        // where J_l A^-1 J_l^T = Y^T Y, Y = L^-1 J_l^T, changes only with the loaded set
        // (LoadedRows: D's tangent block). On a stagger whose normal half ran on the loaded set,
        // J_l v'' and v come from W's impulses without forming v''.
        bool solved = false;
        if (fast && 2 * nl < m) {
          if (loaded != rows.set) build_rows(loaded);
          const auto y_l = rows.y.rightCols(2 * nl);
          dual_sys = rows.d.bottomRightCorner(2 * nl, 2 * nl);
          if (on_set) {  // J_l v'' = c_t + D_tn lambda_n, without forming v''
            rhs_l = rows.c.tail(2 * nl);
            rhs_l.noalias() += rows.d.block(nl, 0, 2 * nl, nl) * lam_w.head(nl);
          } else {
            rhs_l = loaded_tangents(v_second);
          }
          for (int l = 0; l < nl; ++l)
            dual_sys.diagonal().segment<2>(2 * l).array() += 1.0 / weight[l];
          if (small::cholesky_upper(dual_sys.data(), 2 * nl, 2 * nl)) {
            small::cholesky_upper_solve(dual_sys.data(), 2 * nl, 2 * nl, rhs_l.data());
            if (on_set) {  // v = v_free + L^-T Y (lambda_n, -z)
              lam_w.tail(2 * nl) = -rhs_l;
              times(rows.y, lam_w, response);
              upper_solve(response);
              v = v_free + response;
            } else {
              response.noalias() = y_l * rhs_l;
              upper_solve(response);
              v = v_second - response;
            }
            solved = v.allFinite();
          }
        }
        if (!solved) {
          if (on_set) v_second = velocity_after(jn, lam_n);
          for (int l = 0; l < nl; ++l)  // sqrt(w_i) J_t,i stacked: one rank update
            wjt.middleRows(2 * l, 2) = std::sqrt(weight[l]) * jt.middleRows(2 * loaded[l], 2);
          bool primal_done = false;
          if (fast) {
            // (Many loaded nodes: the cross lies on its arms.) J_l^T W J_l by the Gram kernel
            // on a row-major copy padded to its 4-column tiles, the (M + 6)^2 system by the
            // small Cholesky loops.
            const Eigen::Index width = (m + 3) / 4 * 4;
            y_rows.resize(2 * nl, width);  // only the padding needs zeros
            y_rows.rightCols(width - m).setZero();
            y_rows.leftCols(m) = wjt.topRows(2 * nl);
            gram.resize(width, width);
            kernels::gram_lower(y_rows.data(), y_rows.data(), 2 * nl, width, gram.data());
            // cholesky_upper reads the upper triangle only: it gets (A + J_l^T W J_l)'s
            // lower triangle, transposed, in one pass (the same sums as forming the lower
            // triangle and mirroring it, which cost three passes of Eigen's triangular views).
            for (Eigen::Index c = 0; c < m; ++c)
              for (Eigen::Index r = c; r < m; ++r) hess(c, r) = a(r, c) + gram(r, c);
            if (small::cholesky_upper(hess.data(), m, m)) {
              v.noalias() = a * v_second;
              small::cholesky_upper_solve(hess.data(), m, m, v.data());
              primal_done = true;
            }
          }
          if (!primal_done) {
            hess = a;
            hess.selfadjointView<Eigen::Lower>().rankUpdate(wjt.topRows(2 * nl).transpose());
            v = hess.selfadjointView<Eigen::Lower>().llt().solve(a * v_second);
          }
        }
        if (fast) loaded_tangents(v);
        for (int l = 0; l < nl; ++l) {
          const int i = loaded[l];
          ut2 = fast ? Eigen::Vector2d(ut_l.segment<2>(2 * l)) : tangent(i, v);
          lam_t.segment<2>(2 * i) = -weight[l] * ut2;
        }
      }
    }
    timer.stop();
    // Converged when the velocities of the loaded nodes (and of every node's normal, so no
    // unloaded node is about to penetrate) stop changing.
    double change = 0.0;
    if (fast) {
      // The same test as J (v - v_prev), with only the loaded nodes' tangent rows formed.
      dv_stagger = v - v_prev;
      v_prev = v;
      times(jn, dv_stagger, row_gap);
      change = row_gap.cwiseAbs().maxCoeff();
      if (mu > 0.0) {  // the loaded nodes are those with lambda_n > 0
        if (!loaded.empty())
          change = std::max(change, loaded_tangents(dv_stagger).cwiseAbs().maxCoeff());
      } else {
        for (int i = 0; i < k; ++i)
          if (lam_n[i] > 0.0)
            change = std::max(change, tangent(i, dv_stagger).cwiseAbs().maxCoeff());
      }
    } else {
      contact_velocities(vc);
      change = (vc.head(k) - vc_prev.head(k)).cwiseAbs().maxCoeff();
      for (int i = 0; i < k; ++i)
        if (lam_n[i] > 0.0)
          change = std::max(change, (vc.segment<2>(k + 2 * i) - vc_prev.segment<2>(k + 2 * i))
                                        .cwiseAbs()
                                        .maxCoeff());
      vc_prev = vc;
    }
    if (change < tol && !after_jump) {
      ++stagger;
      converged = true;
      break;
    }
    after_jump = false;
    if (fast && stagger + 3 < cfg.max_stagger_iterations) {
      // (No jump in the last staggers: a capped step must end on plain iterates.)
      const double f = extrapolation.observe(lam_n, lam_t, loaded);
      // Where staggering creeps on a held set, Newton on its fixed point first (at most
      // kMaxNewtonTries a step), the Aitken jump if Newton fails.
      if (f > 0.0 && on_set && loaded == rows.set && newton_tries < kMaxNewtonTries) {
        ++newton_tries;
        const int nw = static_cast<int>(rows.set.size());
        ScratchVec &lam_held = sc.lam_held, &b_held = sc.b_held;
        lam_held.resize(2 * nw);
        b_held.resize(nw);
        for (int l = 0; l < nw; ++l) {
          lam_held.segment<2>(2 * l) = lam_t.segment<2>(2 * rows.set[l]);
          b_held[l] = b[rows.set[l]];
        }
        const bool root =
            held_newton.solve(rows.d, rows.c, rows.d_nn, b_held, mu, eps, tol, lam_held);
        if (trace) {
          info.stagger_trace += root ? 'W' : 'w';
          info.stagger_trace += std::to_string(held_newton.iterations());
          if (!root) info.stagger_trace += held_newton.failure();
          info.stagger_trace += ' ';
        }
        if (root) {
          for (int l = 0; l < nw; ++l)
            lam_t.segment<2>(2 * rows.set[l]) = lam_held.segment<2>(2 * l);
          extrapolation.jumped(lam_t);
          // The next stagger is judged against the velocity of Newton's impulses: at a fixed
          // point it reproduces it, and staggering ends one stagger later.
          lam_w.resize(3 * nw);
          held_newton.normal_impulses(lam_held, lam_w.head(nw));
          lam_w.tail(2 * nw) = lam_held;
          times(rows.y, lam_w, v_on);
          upper_solve(v_on);
          v_prev = v_free + v_on;
          continue;
        }
      }
      if (f > 0.0) {
        if (trace) info.stagger_trace += "J ";
        lam_t += f * extrapolation.friction_change();
        extrapolation.jumped(lam_t);
        after_jump = true;
      }
    }
  }
  if (trace) info.stagger_trace += converged ? "ok" : "cap";
  if (!converged) {
    // Capped after a friction half-step: restore the normal constraints with the last
    // friction impulses held, and say that the pair did not settle.
    info.contact_converged = false;
    normal_solve(velocity_after(jt, lam_t));
  }
  for (int i = 0; i < k; ++i) {
    // The reweighted step's impulse -w_i J_t,i v uses the weight of the velocities before the
    // step, so it can leave the Coulomb disc by the last stagger's change (up to ~0.1% was
    // measured): report, and warm-start from, its projection on the disc.
    const double bound = mu * lam_n[i], norm = lam_t.segment<2>(2 * i).norm();
    if (norm > bound) lam_t.segment<2>(2 * i) *= bound / norm;
    impulses[3 * active[i]] = lam_t[2 * i];
    impulses[3 * active[i] + 1] = lam_t[2 * i + 1];
    impulses[3 * active[i] + 2] = lam_n[i];
  }
  return stagger;
}

// Penalty ground: a spring on penetration with damping and regularised Coulomb friction,
// evaluated at the Newton iterate (implicit in position). The default stiffness is sized from
// the weight it must carry: the body's weight shared by the surface nodes that touch the
// ground at rest sinks them by kPenaltySink (1 mm). (The earlier 0.25 m_i / dt^2 let the
// quadruped's feet sink 6 cm.) It is an approximate model, and no longer the fast one: each
// Newton iteration needs the stiffness (its springs are implicit in position), so with the
// fast solver it runs at a sixth to a thirteenth of staggered projection's rate (bench_rom.py).
void ReducedModel::penalty_contacts(const ReducedConfig& cfg, const VecX& q, const VecX& v,
                                    VecX& f, MatX& jac) const {
  const Eigen::Index m = basis_cols_;
  f.setZero(m);
  jac.setZero(m, m);  // d f / d v (position terms are scaled by dt by the caller)
  const double h = cfg.dt;
  const VecX xs = surface_rest_ + surface_rows_ * q;
  const VecX vs = surface_rows_ * v;
  for (size_t c = 0; c < surface_nodes_.size(); ++c) {
    const double z = xs[3 * c + 2] - cfg.ground_height;
    if (z >= 0.0) continue;
    const double mass = node_mass_surface_[c];
    const double k = cfg.penalty_stiffness > 0
                         ? cfg.penalty_stiffness
                         : total_mass_ * std::abs(cfg.gravity.z()) / (rest_contacts_ * kPenaltySink) +
                               mass * 0.25 / (h * h);
    const double damp = 2.0 * std::sqrt(k * mass);
    const double vz = vs[3 * c + 2];
    const double fn = std::max(0.0, -k * z - damp * vz);
    if (fn <= 0.0) continue;
    const auto rows = surface_rows_.middleRows(3 * c, 3);
    f += fn * rows.row(2).transpose();
    // Stiffness (through z = z0 + h v_z) and damping, both on the normal row.
    jac.noalias() -= (k * h + damp) * rows.row(2).transpose() * rows.row(2);
    const Eigen::Vector2d vt(vs[3 * c], vs[3 * c + 1]);
    const double eps = 1e-3;
    const double s = std::sqrt(vt.squaredNorm() + eps * eps);
    const double scale = cfg.friction * fn / s;
    f -= scale * (rows.topRows(2).transpose() * vt);
    // Exact Jacobian of -mu f_n v_t / |v_t|_eps in v_t: (mu f_n / s)(I - v_t v_t^T / s^2).
    const Eigen::Matrix2d dt_dv =
        scale * (Eigen::Matrix2d::Identity() - vt * vt.transpose() / (s * s));
    jac.noalias() -= rows.topRows(2).transpose() * dt_dv * rows.topRows(2);
  }
}

}  // namespace softrom
