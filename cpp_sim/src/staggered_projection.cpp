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
// impulses: k contact rows of rank <= M + 6 make the impulses non-unique (the Delassus
// operator J A^-1 J^T is singular, or nearly: condition numbers ~1e6), so Gauss-Seidel on
// impulses crawls, while the primal problems are strongly convex and small. (The fast solver
// forms the Delassus operator only on the loaded set's few rows: LoadedRows.) The normal half
// is solved exactly as a least-distance programme, the friction half (maximal dissipation) by
// a reweighted least-squares step on |J_t,i v|_eps = sqrt(|J_t,i v|^2 + eps^2). A step that
// reaches the cap ends with one more normal solve, so the normal constraints hold even then
// (reported in info). In the fast solver, a stagger whose loaded set is the last one's (most
// of them) runs both halves over that set's impulses (LoadedRows), falling back to NNLS when
// a node leaves or joins; where the staggers creep on a held set, Newton on its fixed point
// (HeldSetNewton) or an Aitken jump (StaggerExtrapolation) shortens them
// (stagger_acceleration.h).
#include "staggered_projection.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <string>

#include "dense_kernels.h"
#include "small_cholesky.h"

namespace softrom {

int StaggeredProjection::solve(const ReducedConfig& cfg, const RowMatX& surface_rows,
                               const std::vector<int>& active, const std::vector<double>& gap,
                               const MatX& a, const Eigen::LLT<MatX>& a_llt, VecX& v,
                               VecX& impulses, NnlsWorkspace& nnls, StepInfo& info,
                               const std::vector<double>* drift) {
  cfg_ = &cfg;
  a_ = &a;
  a_llt_ = &a_llt;
  v_ = &v;
  nnls_ = &nnls;
  info_ = &info;
  m_ = a.rows();
  k_ = static_cast<int>(active.size());
  fast_ = cfg.solver == Solver::Fast;
  how_ = fast_ ? NnlsSolve::Gram : NnlsSolve::Qr;
  mu_ = cfg.friction;
  tol_ = cfg.contact_tolerance;
  eps_ = cfg.friction_eps();  // smoothing of |v_t|: sticking nodes creep at most ~eps
  set_up(surface_rows, active);
  return run(active, gap, drift, impulses);
}

int StaggeredProjection::resolve(const std::vector<int>& active, const std::vector<double>& gap,
                                 const std::vector<double>* drift, VecX& v, VecX& impulses,
                                 StepInfo& info) {
  assert(static_cast<int>(active.size()) == k_ && v.size() == m_);
  v_ = &v;
  info_ = &info;
  return run(active, gap, drift, impulses);
}

int StaggeredProjection::run(const std::vector<int>& active, const std::vector<double>& gap,
                             const std::vector<double>* drift, VecX& impulses) {
  const ReducedConfig& cfg = *cfg_;
  StepInfo& info = *info_;
  const int k = k_;
  const bool fast = fast_;
  const double tol = tol_;
  start(active, gap, drift, impulses);
  impulses.setZero();

  // With config.profile, the stagger loop's course in info.stagger_trace (StepInfo's grammar).
  const bool trace = cfg.profile;
  if (trace && !info.stagger_trace.empty()) info.stagger_trace += " R ";  // a re-solve
  if (trace) trace_start();
  int stagger = 0;
  bool converged = false;
  extrapolation_.reset(lam_n_, lam_t_);
  bool after_jump = false;  // the stagger after a jump may not declare convergence
  constexpr int kMaxNewtonTries = 3;
  int newton_tries = 0;
  for (; stagger < cfg.max_stagger_iterations; ++stagger) {
    // --- Normal problem with the friction impulses held fixed.
    const bool on_set = fast && normal_on_loaded_set();
    if (!on_set) normal_solve(velocity_after(jt_, lam_t_));
    if (trace) trace_normal(on_set);
    // --- Friction problem with the normal impulses held fixed.
    if (!on_set) v_second_ = velocity_after(jn_, lam_n_);
    friction_half(on_set);
    const double change = stagger_change();
    if (change < tol && !after_jump) {
      ++stagger;
      converged = true;
      break;
    }
    after_jump = false;
    if (fast && stagger + 3 < cfg.max_stagger_iterations) {
      // (No jump in the last staggers: a capped step must end on plain iterates.)
      const double f = extrapolation_.observe(lam_n_, lam_t_, loaded_);
      // Where staggering creeps on a held set, Newton on its fixed point first (at most
      // kMaxNewtonTries a step), the Aitken jump if Newton fails.
      if (f > 0.0 && on_set && loaded_ == rows_.set && newton_tries < kMaxNewtonTries) {
        ++newton_tries;
        if (held_set_newton()) continue;
      }
      if (f > 0.0) {
        if (trace) info.stagger_trace += "J ";
        lam_t_ += f * extrapolation_.friction_change();
        extrapolation_.jumped(lam_t_);
        after_jump = true;
      }
    }
  }
  if (trace) info.stagger_trace += converged ? "ok" : "cap";
  if (!converged) {
    // Capped after a friction half-step: restore the normal constraints with the last
    // friction impulses held, and say that the pair did not settle.
    info.contact_converged = false;
    normal_solve(velocity_after(jt_, lam_t_));
  } else if (normal_violation() > tol) {
    // Converged after a friction half-step that left a candidate below its bound by more
    // than the tolerance: restore the normal constraints the same way. The stopping test
    // bounds the last stagger's change, and a loaded node's end violation is the friction
    // half's own normal shift W_nt (lambda_t^k - lambda_t^(k-1)), whose change from stagger
    // to stagger that test sees: where staggering contracts slowly (rate rho) the violation
    // is rho / (1 - rho) times the change (measured: up to 5.5 tol dt on the cross's gait at
    // the default dt, 13-16 under random forces at dt = 0.02; now under 1 in the linear frame
    // and 1.7 in the floating; benchmarks/PROFILE.md, session 53).
    if (trace) info.stagger_trace += " n";
    normal_solve(velocity_after(jt_, lam_t_));
  }
  for (int i = 0; i < k; ++i) {
    // The reweighted step's impulse -w_i J_t,i v uses the weight of the velocities before the
    // step, so it can leave the Coulomb disc: report, and warm-start from, its projection on
    // the disc. (The velocity is the unprojected impulse's. On converged walking steps it left
    // the disc by more than 1 % on 4-11 % of the reference's steps and 1-3 % of the fast
    // solver's, by up to 1.4x on a few. Re-taking the normal half with the projected friction
    // held moved no solver nearer a tight solve; benchmarks/PROFILE.md, session 52.)
    const double bound = mu_ * lam_n_[i], norm = lam_t_.segment<2>(2 * i).norm();
    if (norm > bound) lam_t_.segment<2>(2 * i) *= bound / norm;
    impulses[3 * active[i]] = lam_t_[2 * i];
    impulses[3 * active[i] + 1] = lam_t_[2 * i + 1];
    impulses[3 * active[i] + 2] = lam_n_[i];
  }
  return stagger;
}

void StaggeredProjection::set_up(const RowMatX& surface_rows, const std::vector<int>& active) {
  const Eigen::LLT<MatX>& a_llt = *a_llt_;
  const Eigen::Index m = m_;
  const int k = k_;
  const bool fast = fast_;
  jn_.resize(k, m);
  jt_.resize(2 * k, m);
  for (int i = 0; i < k; ++i) {
    const int c = active[i];
    jn_.row(i) = surface_rows.row(3 * c + 2);
    jt_.row(2 * i) = surface_rows.row(3 * c);
    jt_.row(2 * i + 1) = surface_rows.row(3 * c + 1);
  }
  // Constant within the step: E^T = L^-1 J_n^T (the LDP's constraint matrix). The velocity
  // response to the impulses, A^-1 J^T lambda, is two triangular solves per stagger: forming
  // A^-1 J_n^T and A^-1 J_t^T once instead takes 3k right-hand sides (k candidates; ~130k
  // multiply-adds on the quadruped) for per-stagger products no cheaper than the solves.
  g_.resize(m + 1, k);
  // The fast solver's g^T = [E  b - J_n v'] (k x m + 1), for NNLS's gradient.
  if (fast) {
    // jn's column-major memory is J_n^T row by row: solve in a copy, then transpose into g.
    // The copy, read as a column-major k x m matrix, is E = J_n L^-T itself.
    et_rows_ = jn_;
    kernels::lower_solve_rows(a_llt.matrixLLT().data(), m, et_rows_.data(), k);
    g_.topRows(m) = Eigen::Map<const RowMatX>(et_rows_.data(), m, k);
    gt_.resize(k, m + 1);
    gt_.leftCols(m) = et_rows_;
  } else {
    g_.topRows(m) = a_llt.matrixL().solve(jn_.transpose());
  }
  // The fast solver applies L^-1 and L^-T (A = L L^T) as products with explicit inverses,
  // formed once per step (L^-1's rows by the row-oriented substitution, an (M + 6)^3 / 6 sum;
  // the ~50 solves of a quadruped step each become a vectorised product); the reference
  // solves by substitution.
  solve_tmp_.resize(m);
  if (fast) {
    l_inv_t_.setIdentity(m, m);  // row-major L^-1 is column-major L^-T
    kernels::lower_solve_rows(a_llt.matrixLLT().data(), m, l_inv_t_.data(), m);
    l_inv_ = l_inv_t_.transpose();
  }
  response_.resize(m);
  // Per-stagger buffers (row_gap: a J_n product).
  x_ldp_.resize(m);
  lam_ldp_.resize(k);
  row_gap_.resize(k);
  weight_.resize(k);
  dv_stagger_.resize(m);
  v_second_.resize(m);
  hess_.resize(m, m);
  wjt_.resize(2 * k, m);
  v_on_.resize(m);
  tangent_row_.resize(m);
  // Every candidate that has been in a loaded set during this step (the pool, ~10 on a
  // quadruped step) keeps its three columns of Y = L^-1 [J_n,i^T  J_t,i^T], their products
  // with every other pool column (the pool's Gram matrix) and c_i = J_i v_free, so that a new
  // loaded set (~5 per quadruped step) gathers its D and c instead of forming them: only a
  // candidate's first entry costs a triangular solve and its columns' products with the pool.
  // (The pool's memory is the worker's: its capacity may be a former step's. A re-solve of
  // the step keeps the pool: v_free is the same.)
  pool_slot_.assign(k, -1);
  pool_size_ = 0;
  pool_y_.resize(m, 0);  // empty, as the pool starts each step (the memory stays)
  pool_gram_.resize(0, 0);
  pool_c_.resize(0);
}

void StaggeredProjection::start(const std::vector<int>& active, const std::vector<double>& gap,
                                const std::vector<double>* drift, const VecX& impulses) {
  const ReducedConfig& cfg = *cfg_;
  const VecX& v = *v_;
  const Eigen::Index m = m_;
  const int k = k_;
  const bool fast = fast_;
  const double h = cfg.dt;
  old_ = impulses;
  b_.resize(k);
  lam_n_.resize(k);
  lam_t_.resize(2 * k);
  for (int i = 0; i < k; ++i) {
    const int c = active[i];
    b_[i] = cfg.normal_velocity_bound(gap[i]);
    if (drift) b_[i] -= (*drift)[i] / h;
    lam_n_[i] = std::max(old_[3 * c + 2], 0.0);  // warm start by node id
    lam_t_.segment<2>(2 * i) = old_.segment<2>(3 * c);
  }
  v_free_ = v;
  nnls_->carry_valid = false;  // b changes: no factor carries over into the solve
  // The first stagger is judged against the warm start's velocity, v* + A^-1 J^T lambda_0,
  // the iterate it continues. Judged against v* (as it was until session 51), a first stagger
  // whose normal half found the warm start's friction alone enough to lift every candidate
  // unloaded them all, so its friction half returned v* itself, and the step "converged" at
  // zero impulses with the normal conditions violated (a beam node 0.02 mm into the ground).
  v_prev_ = warm_start_velocity();
  if (!fast) {  // the reference compares all 3k contact velocities stagger to stagger
    vc_prev_.resize(3 * k);
    vc_.resize(3 * k);
    vc_prev_.head(k).noalias() = jn_ * v_prev_;
    vc_prev_.tail(2 * k).noalias() = jt_ * v_prev_;
  }
  loaded_.clear();
  // The loaded nodes' tangent rows J_t,l (2 nl x (M + 6), column-major), gathered when the loaded
  // set changes, so that their tangential velocities are one product (fast solver).
  jt_l_.resize(0, m);
  jt_l_set_.clear();
  rows_.reset(k);
}

template <class Matrix, class Vector>
void StaggeredProjection::times(const Matrix& a, const Vector& x, ScratchVec& out) const {
  if (fast_) {
    out.resize(a.rows());
    kernels::cols_times(a.data(), a.rows(), a.cols(), x.data(), out.data());
  } else {
    out.noalias() = a * x;
  }
}

// x <- L^-T x with A = L L^T: the product with L^-T (fast), substitution on U = L^T (reference).
void StaggeredProjection::upper_solve(ScratchVec& x) {
  if (fast_) {
    kernels::cols_times(l_inv_t_.data(), m_, m_, x.data(), solve_tmp_.data());
    x = solve_tmp_;
  } else {
    a_llt_->matrixU().solveInPlace(x);
  }
}

// J_t,i x for candidate i (its two tangent rows): a loop over J_t's column-major memory in the
// fast solver (Eigen's general matrix-vector product costs more to set up than the 2 M
// multiply-adds), Eigen's product in the reference.
template <class Vector>
Eigen::Vector2d StaggeredProjection::tangent(int i, const Vector& x) const {
  if (!fast_) return jt_.middleRows(2 * i, 2) * x;
  const double* p = jt_.data() + 2 * i;
  const Eigen::Index ld = jt_.rows();
  double s0 = 0.0, s1 = 0.0;
  for (Eigen::Index r = 0; r < m_; ++r) {
    s0 += p[r * ld] * x[r];
    s1 += p[r * ld + 1] * x[r];
  }
  return {s0, s1};
}

// v_free + A^-1 J^T lambda: the velocity after impulses lambda on the rows j (J_n or J_t).
const ScratchVec& StaggeredProjection::velocity_after(const ScratchMat& j, const ScratchVec& lam) {
  const Eigen::Index m = m_;
  if (fast_) {
    // Only loaded nodes carry impulses (~7 of 64 candidates on a walker): J^T lambda from
    // their rows, not a product over every row; then A^-1 = L^-T L^-1 as two products.
    response_.setZero();
    for (Eigen::Index i = 0; i < lam.size(); ++i)
      if (lam[i] != 0.0) response_.noalias() += lam[i] * j.row(i).transpose();
    kernels::cols_times(l_inv_.data(), m, m, response_.data(), solve_tmp_.data());
    kernels::cols_times(l_inv_t_.data(), m, m, solve_tmp_.data(), response_.data());
  } else {
    response_.noalias() = j.transpose() * lam;
    a_llt_->solveInPlace(response_);
  }
  response_ += v_free_;
  return response_;
}

const ScratchVec& StaggeredProjection::warm_start_velocity() {
  if (lam_n_.isZero(0.0) && lam_t_.isZero(0.0)) {
    response_ = v_free_;
    return response_;
  }
  const Eigen::Index m = m_;
  if (fast_) {
    response_.setZero();
    for (int i = 0; i < k_; ++i) {
      if (lam_n_[i] != 0.0) response_.noalias() += lam_n_[i] * jn_.row(i).transpose();
      for (int t = 0; t < 2; ++t)
        if (lam_t_[2 * i + t] != 0.0)
          response_.noalias() += lam_t_[2 * i + t] * jt_.row(2 * i + t).transpose();
    }
    kernels::cols_times(l_inv_.data(), m, m, response_.data(), solve_tmp_.data());
    kernels::cols_times(l_inv_t_.data(), m, m, solve_tmp_.data(), response_.data());
  } else {
    response_.noalias() = jn_.transpose() * lam_n_;
    response_.noalias() += jt_.transpose() * lam_t_;
    a_llt_->solveInPlace(response_);
  }
  response_ += v_free_;
  return response_;
}

// The loaded nodes' tangential velocities J_t,l x (fast solver).
template <class Vector>
const ScratchVec& StaggeredProjection::loaded_tangents(const Vector& x) {
  if (jt_l_set_ != loaded_) {
    jt_l_.resize(2 * static_cast<Eigen::Index>(loaded_.size()), m_);
    for (size_t l = 0; l < loaded_.size(); ++l)
      jt_l_.middleRows(2 * l, 2) = jt_.middleRows(2 * loaded_[l], 2);
    jt_l_set_ = loaded_;
  }
  times(jt_l_, x, ut_l_);
  return ut_l_;
}

void StaggeredProjection::normal_solve(const ScratchVec& v_prime) {
  // With A = L L^T and x = L^T (v - v'), the normal problem is the least-distance programme
  // min |x| s.t. J_n L^-T x >= b - J_n v', solved exactly by NNLS (Lawson & Hanson), whose
  // active set copes with the redundant rows; the multipliers are the normal impulses.
  StepInfo& info = *info_;
  VecX& v = *v_;
  const Eigen::Index m = m_;
  const bool fast = fast_;
  ++info.normal_iterations;
  ScopedTimer timer(cfg_->profile ? &info.time_normal : nullptr);
  times(jn_, v_prime, row_gap_);
  g_.row(m) = (b_ - row_gap_).transpose();
  if (fast) gt_.col(m) = g_.row(m).transpose();
  lam_ldp_ = lam_n_;  // warm start: last stagger's (or step's) loaded nodes
  bool nnls_ok = true;
  if (least_distance(g_, x_ldp_, lam_ldp_, nnls_ok, how_, *nnls_, fast ? gt_.data() : nullptr,
                     fast)) {
    upper_solve(x_ldp_);
    v = v_prime + x_ldp_;
    lam_n_ = lam_ldp_;
  } else {
    // In exact arithmetic unreachable for a ground plane (moving up is always feasible); in
    // floating point reached when a gap is absurd (a ground 1e6 m above the body). The
    // constraints are then not enforced at all, so the step is reported as diverged (the
    // state keeps its last good value) rather than accepted as free flight.
    v = v_prime;
    lam_n_.setZero();
    nnls_ok = false;
    info.diverged = true;
  }
  // The LDP's answer must be feasible: every candidate ends on or above its bound.
  if (nnls_ok) {
    times(jn_, v, row_gap_);
    const double worst = (b_ - row_gap_).maxCoeff();
    if (worst > tol_) nnls_ok = false;
  }
  if (!nnls_ok) info.contact_converged = false;
}

// Candidates join the pool (see set_up) when they first enter a loaded set.
void StaggeredProjection::enter_pool(const std::vector<int>& set) {
  const Eigen::Index m = m_;
  const int k = k_;
  int fresh = 0;
  for (int i : set) fresh += pool_slot_[i] < 0;
  if (fresh == 0) return;
  const int old = pool_size_, total = old + fresh;
  if (pool_y_.cols() < 3 * total) {  // grow, keeping the columns and products formed so far
    const Eigen::Index cap =
        std::min<Eigen::Index>(3 * k, std::max<Eigen::Index>(3 * total + 12, 2 * pool_y_.cols()));
    pool_y_.conservative_resize(m, cap);
    pool_gram_.conservative_resize(cap, cap);
    pool_c_.conservative_resize(cap, 1);
  }
  // The new candidates' L^-1 J_t,i^T as products with L^-1 (formed once per step): one or two
  // candidates enter at a time, too few right-hand sides for the row-wise substitution to
  // vectorise (~13 k instructions an entry on the quadruped, by callgrind).
  int f = 0;
  for (int i : set)
    if (pool_slot_[i] < 0) pool_slot_[i] = old + f++;
  for (int i : set) {
    const int p = pool_slot_[i];
    if (p < old) continue;
    pool_y_.col(3 * p) = g_.col(i).head(m);
    for (int t = 0; t < 2; ++t) {
      tangent_row_ = jt_.row(2 * i + t).transpose();
      kernels::cols_times(l_inv_.data(), m, m, tangent_row_.data(),
                          pool_y_.col(3 * p + 1 + t).data());
    }
    pool_c_[3 * p] = jn_.row(i).dot(v_free_);
    pool_c_.segment<2>(3 * p + 1) = tangent(i, v_free_);
  }
  // The new columns against every pool column (the new ones included), then the mirror.
  pool_gram_.block(0, 3 * old, 3 * total, 3 * fresh).noalias() =
      pool_y_.leftCols(3 * total).transpose() * pool_y_.middleCols(3 * old, 3 * fresh);
  pool_gram_.block(3 * old, 0, 3 * fresh, 3 * old) =
      pool_gram_.block(0, 3 * old, 3 * old, 3 * fresh).transpose();
  pool_size_ = total;
}

// The loaded set's rows (LoadedRows) for `set`, gathered from the pool.
void StaggeredProjection::build_rows(const std::vector<int>& set) {
  const int nw = static_cast<int>(set.size());
  for (int i : rows_.set) rows_.member[i] = 0;
  rows_.set = set;
  for (int i : set) rows_.member[i] = 1;
  enter_pool(set);
  // Y's columns: the normals of W, then each node's two tangents; D and c gathered alike.
  slots_.resize(3 * nw);
  for (int l = 0; l < nw; ++l) {
    const Eigen::Index p = pool_slot_[set[l]];
    slots_[l] = 3 * p;
    slots_[nw + 2 * l] = 3 * p + 1;
    slots_[nw + 2 * l + 1] = 3 * p + 2;
  }
  rows_.y.resize(m_, 3 * nw);
  rows_.c.resize(3 * nw);
  rows_.d.resize(3 * nw, 3 * nw);
  for (int a = 0; a < 3 * nw; ++a) {
    rows_.y.col(a) = pool_y_.col(slots_[a]);
    rows_.c[a] = pool_c_[slots_[a]];
  }
  for (int b = 0; b < 3 * nw; ++b)
    for (int a = 0; a < 3 * nw; ++a) rows_.d(a, b) = pool_gram_(slots_[a], slots_[b]);
  rows_.d_nn = rows_.d.topLeftCorner(nw, nw);
  rows_.normal_ok = small::cholesky_upper(rows_.d_nn.data(), nw, nw);
}

// The normal half on the last stagger's loaded set W: J_n,W v = b_W with the friction
// impulses held, i.e. D_nn lambda_n = b_W - c_n - D_nt lambda_t. It is the least-distance
// programme's answer (the same velocity as NNLS, to round-off) when lambda_n > 0 and every
// other candidate ends on or above its bound; otherwise (a node leaves or joins) it returns
// false and NNLS runs. The bound is met to within kSlack (1e-5 of the default contact
// tolerance; NNLS adds a violated candidate at a similar level).
bool StaggeredProjection::normal_on_loaded_set() {
  constexpr double kSlack = 1e-9;
  StepInfo& info = *info_;
  const int k = k_;
  const int nw = static_cast<int>(rows_.set.size());
  if (nw == 0 || !rows_.normal_ok || loaded_ != rows_.set) return false;
  for (int i = 0; i < k; ++i)  // friction off W (a jump's) would not be held
    if (!rows_.member[i] && (lam_t_[2 * i] != 0.0 || lam_t_[2 * i + 1] != 0.0)) return false;
  ScopedTimer timer(cfg_->profile ? &info.time_normal : nullptr);
  lam_w_.resize(3 * nw);
  rhs_l_.resize(nw);
  for (int l = 0; l < nw; ++l) {
    lam_w_.segment<2>(nw + 2 * l) = lam_t_.segment<2>(2 * rows_.set[l]);
    rhs_l_[l] = b_[rows_.set[l]] - rows_.c[l];
  }
  rhs_l_.noalias() -= rows_.d.block(0, nw, nw, 2 * nw) * lam_w_.tail(2 * nw);
  small::cholesky_upper_solve(rows_.d_nn.data(), nw, nw, rhs_l_.data());
  if (!(rhs_l_.array() > 0.0).all()) return false;
  lam_w_.head(nw) = rhs_l_;
  times(rows_.y, lam_w_, v_on_);
  upper_solve(v_on_);
  v_on_ += v_free_;
  times(jn_, v_on_, row_gap_);
  for (int i = 0; i < k; ++i)
    if (!rows_.member[i] && b_[i] - row_gap_[i] > kSlack) return false;
  *v_ = v_on_;
  lam_n_.setZero();
  for (int l = 0; l < nw; ++l) lam_n_[rows_.set[l]] = rhs_l_[l];
  ++info.normal_iterations;
  return true;
}

void StaggeredProjection::trace_start() {
  traced_.resize(k_);
  for (int i = 0; i < k_; ++i) traced_[i] = lam_n_[i] > 0.0;  // the warm start's loaded set
}

void StaggeredProjection::trace_normal(bool on_set) {
  int n = 0, entered = 0, left = 0;
  for (int i = 0; i < k_; ++i) {
    const char now = lam_n_[i] > 0.0;
    n += now;
    entered += now && !traced_[i];
    left += !now && traced_[i];
    traced_[i] = now;
  }
  std::string& t = info_->stagger_trace;
  t += on_set ? 'S' : 'N';
  t += std::to_string(n);
  if (entered > 0 || left > 0)
    t += "(+" + std::to_string(entered) + "-" + std::to_string(left) + ")";
  t += ' ';
}

// The friction problem with the normal impulses held fixed: one reweighted least-squares step
// on the smoothed, strictly convex
//   phi(v) = 1/2 |v - v''|_A^2 + sum_i c_i sqrt(|J_t,i v|^2 + eps^2),  c_i = mu lambda_n,i:
// v minimises phi's quadratic majoriser at the current velocities, so phi decreases and the
// friction impulses -c_i J_t,i v / |J_t,i v|_eps stay inside the Coulomb discs. The stagger
// loop iterates to the joint fixed point. (Measured on the quadruped: staggering converges
// linearly at a rate near 0.95 per stagger; solving this half to convergence by Newton's
// method made it oscillate instead: the slow part is the normal-friction coupling, a sliding
// node's load creeping up stagger by stagger, which Newton on the held set's fixed point
// (HeldSetNewton) or else the guarded Aitken jump shortens. Anderson acceleration of the
// stagger map on the loaded friction impulses, restarted when the loaded set changes or the
// residual grows, took 1-22 % fewer staggers than the Aitken jump but stopped further from
// the converged step on three of eight gait and random rows, and saved 1-4 % of a step's
// instructions: benchmarks/PROFILE.md, session 21.)
void StaggeredProjection::friction_half(bool on_set) {
  StepInfo& info = *info_;
  const MatX& a = *a_;
  VecX& v = *v_;
  const Eigen::Index m = m_;
  const int k = k_;
  const bool fast = fast_;
  const double mu = mu_, eps = eps_;
  ++info.friction_iterations;
  ScopedTimer timer(cfg_->profile ? &info.time_friction : nullptr);
  // Only loaded nodes (lambda_n > 0) carry friction: the others have zero weight.
  loaded_.clear();
  for (int i = 0; i < k; ++i)
    if (lam_n_[i] > 0.0 && mu > 0.0) loaded_.push_back(i);
  const int nl = static_cast<int>(loaded_.size());
  lam_t_.setZero();
  if (nl == 0) {
    v = v_second_;
    return;
  }
  const ScratchVec* ut_fast = fast ? &loaded_tangents(v) : nullptr;
  for (int l = 0; l < nl; ++l) {
    const int i = loaded_[l];
    const Eigen::Vector2d ut = fast ? Eigen::Vector2d(ut_fast->segment<2>(2 * l)) : tangent(i, v);
    weight_[l] = mu * lam_n_[i] / std::sqrt(ut.squaredNorm() + eps * eps);
  }
  // The step solves (A + J_l^T W J_l) v = A v'' (J_l: the loaded nodes' tangent rows, W their
  // weights). With fewer rows than coordinates (2 nl < M + 6: a walker stands on ~7 nodes) it
  // is solved in the rows' space instead (Woodbury):
  //   v = v'' - A^-1 J_l^T (W^-1 + J_l A^-1 J_l^T)^-1 J_l v'',
  // where J_l A^-1 J_l^T = Y^T Y, Y = L^-1 J_l^T, changes only with the loaded set (LoadedRows:
  // D's tangent block). On a stagger whose normal half ran on the loaded set, J_l v'' and v
  // come from W's impulses without forming v''.
  bool solved = false;
  if (fast && 2 * nl < m) {
    if (loaded_ != rows_.set) build_rows(loaded_);
    const auto y_l = rows_.y.rightCols(2 * nl);
    dual_sys_ = rows_.d.bottomRightCorner(2 * nl, 2 * nl);
    if (on_set) {  // J_l v'' = c_t + D_tn lambda_n, without forming v''
      rhs_l_ = rows_.c.tail(2 * nl);
      rhs_l_.noalias() += rows_.d.block(nl, 0, 2 * nl, nl) * lam_w_.head(nl);
    } else {
      rhs_l_ = loaded_tangents(v_second_);
    }
    for (int l = 0; l < nl; ++l)
      dual_sys_.diagonal().segment<2>(2 * l).array() += 1.0 / weight_[l];
    if (small::cholesky_upper(dual_sys_.data(), 2 * nl, 2 * nl)) {
      small::cholesky_upper_solve(dual_sys_.data(), 2 * nl, 2 * nl, rhs_l_.data());
      if (on_set) {  // v = v_free + L^-T Y (lambda_n, -z)
        lam_w_.tail(2 * nl) = -rhs_l_;
        times(rows_.y, lam_w_, response_);
        upper_solve(response_);
        v = v_free_ + response_;
      } else {
        response_.noalias() = y_l * rhs_l_;
        upper_solve(response_);
        v = v_second_ - response_;
      }
      solved = v.allFinite();
    }
  }
  if (!solved) {
    if (on_set) v_second_ = velocity_after(jn_, lam_n_);
    bool primal_done = false;
    if (fast) {
      // (Many loaded nodes: the cross lies on its arms.) J_l^T W J_l by the Gram kernel on
      // sqrt(w_i) J_t,i stacked row-major, each row padded with zeros to the kernel's 4-column
      // tiles, gathered from J_t in one pass (a column-major stack, then a row-major copy and
      // Eigen's zeroing of the padding, a memset per row, were ~4 % of the cross's step).
      const Eigen::Index width = (m + 3) / 4 * 4, jt_ld = jt_.rows();
      y_rows_.resize(2 * nl, width);
      for (int l = 0; l < nl; ++l) {
        const double root = std::sqrt(weight_[l]);
        for (int t = 0; t < 2; ++t) {
          const double* src = jt_.data() + 2 * loaded_[l] + t;
          double* dst = y_rows_.data() + (2 * l + t) * width;
          for (Eigen::Index c = 0; c < m; ++c) dst[c] = root * src[c * jt_ld];
          for (Eigen::Index c = m; c < width; ++c) dst[c] = 0.0;
        }
      }
      gram_.resize(width, width);
      kernels::gram_lower(y_rows_.data(), y_rows_.data(), 2 * nl, width, gram_.data());
      // (A + J_l^T W J_l)'s lower triangle, on the three zero rows of padding the lower
      // Cholesky kernel reads: its column updates are vectorised (0.54x the scalar loops' time
      // at M + 6 = 26, for the same factor to the bit).
      hess_.resize(m + 3, m);
      for (Eigen::Index c = 0; c < m; ++c) {
        for (Eigen::Index r = c; r < m; ++r) hess_(r, c) = a(r, c) + gram_(r, c);
        hess_(m, c) = hess_(m + 1, c) = hess_(m + 2, c) = 0.0;
      }
      if (kernels::cholesky_lower(hess_.data(), m, m + 3)) {
        v.noalias() = a * v_second_;
        small::cholesky_lower_solve(hess_.data(), m, m + 3, v.data());
        primal_done = true;
      }
    }
    if (!primal_done) {
      for (int l = 0; l < nl; ++l)  // sqrt(w_i) J_t,i stacked: one rank update
        wjt_.middleRows(2 * l, 2) = std::sqrt(weight_[l]) * jt_.middleRows(2 * loaded_[l], 2);
      hess_ = a;
      hess_.selfadjointView<Eigen::Lower>().rankUpdate(wjt_.topRows(2 * nl).transpose());
      v = hess_.selfadjointView<Eigen::Lower>().llt().solve(a * v_second_);
    }
  }
  if (fast) loaded_tangents(v);
  for (int l = 0; l < nl; ++l) {
    const int i = loaded_[l];
    const Eigen::Vector2d ut2 = fast ? Eigen::Vector2d(ut_l_.segment<2>(2 * l)) : tangent(i, v);
    lam_t_.segment<2>(2 * i) = -weight_[l] * ut2;
  }
}

// The most any candidate's normal velocity lies below its bound, b_i - J_n,i v.
double StaggeredProjection::normal_violation() {
  times(jn_, *v_, row_gap_);
  return (b_ - row_gap_).maxCoeff();
}

// How far the last stagger moved the contact nodes' velocities: the loaded nodes' (and every
// node's normal, so no unloaded node is about to penetrate). Staggering has converged when it
// is below the contact tolerance.
double StaggeredProjection::stagger_change() {
  const VecX& v = *v_;
  const int k = k_;
  double change = 0.0;
  if (fast_) {
    // The same test as J (v - v_prev), with only the loaded nodes' tangent rows formed.
    dv_stagger_ = v - v_prev_;
    v_prev_ = v;
    times(jn_, dv_stagger_, row_gap_);
    change = row_gap_.cwiseAbs().maxCoeff();
    if (mu_ > 0.0) {  // the loaded nodes are those with lambda_n > 0
      if (!loaded_.empty())
        change = std::max(change, loaded_tangents(dv_stagger_).cwiseAbs().maxCoeff());
    } else {
      for (int i = 0; i < k; ++i)
        if (lam_n_[i] > 0.0)
          change = std::max(change, tangent(i, dv_stagger_).cwiseAbs().maxCoeff());
    }
  } else {
    vc_.head(k).noalias() = jn_ * v;
    vc_.tail(2 * k).noalias() = jt_ * v;
    change = (vc_.head(k) - vc_prev_.head(k)).cwiseAbs().maxCoeff();
    for (int i = 0; i < k; ++i)
      if (lam_n_[i] > 0.0)
        change = std::max(
            change,
            (vc_.segment<2>(k + 2 * i) - vc_prev_.segment<2>(k + 2 * i)).cwiseAbs().maxCoeff());
    vc_prev_ = vc_;
  }
  return change;
}

// Newton on the held set's fixed point (HeldSetNewton). On a root, W's friction impulses are
// set to it and the next stagger is judged against the velocity of Newton's impulses: at a
// fixed point it reproduces it, and staggering ends one stagger later.
bool StaggeredProjection::held_set_newton() {
  const int nw = static_cast<int>(rows_.set.size());
  lam_held_.resize(2 * nw);
  b_held_.resize(nw);
  for (int l = 0; l < nw; ++l) {
    lam_held_.segment<2>(2 * l) = lam_t_.segment<2>(2 * rows_.set[l]);
    b_held_[l] = b_[rows_.set[l]];
  }
  const bool root =
      held_newton_.solve(rows_.d, rows_.c, rows_.d_nn, b_held_, mu_, eps_, tol_, lam_held_);
  if (cfg_->profile) {
    std::string& t = info_->stagger_trace;
    t += root ? 'W' : 'w';
    t += std::to_string(held_newton_.iterations());
    if (!root) t += held_newton_.failure();
    t += ' ';
  }
  if (!root) return false;
  for (int l = 0; l < nw; ++l) lam_t_.segment<2>(2 * rows_.set[l]) = lam_held_.segment<2>(2 * l);
  extrapolation_.jumped(lam_t_);
  lam_w_.resize(3 * nw);
  held_newton_.normal_impulses(lam_held_, lam_w_.head(nw));
  lam_w_.tail(2 * nw) = lam_held_;
  times(rows_.y, lam_w_, v_on_);
  upper_solve(v_on_);
  v_prev_ = v_free_ + v_on_;
  return true;
}

}  // namespace softrom
