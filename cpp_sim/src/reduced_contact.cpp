// Ground contact: staggered projection (the default, Kaufman et al. 2008) and a penalty model.
#include <algorithm>
#include <cmath>

#include "nnls.h"
#include "reduced_model.h"

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
  StaggerExtrapolation(const VecX& lam_n, const VecX& lam_t)
      : k_(lam_n.size()), last_(3 * k_), d_(3 * k_), d_prev_(3 * k_) {
    last_ << lam_n, lam_t;
    loaded_.reserve(k_);
  }

  // The impulses at the end of a stagger; returns the factor f of the jump
  // lambda_t += f (lambda_t - lambda_t,prev), 0 for none.
  double observe(const VecX& lam_n, const VecX& lam_t, const std::vector<int>& loaded) {
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
  void jumped(const VecX& lam_t) {
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
  Eigen::Index k_;
  VecX last_, d_, d_prev_;  // (lambda_n, lambda_t): the last impulses and their changes
  std::vector<int> loaded_;
  int held_ = 0, jumps_ = 0;
  bool have_d_ = false;
};

}  // namespace

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
// constraints hold even when staggering stops at its cap (reported in info).
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
  const VecX z_all = normal_rows_ * q;
  const VecX vn_all = normal_rows_ * v;
  std::vector<int> active;
  std::vector<double> gap;
  for (int c = 0; c < ns; ++c) {
    const double z = surface_rest_[3 * c + 2] + z_all[c] - cfg.ground_height;
    if (z + 2.0 * h * std::min(vn_all[c], 0.0) < cfg.contact_margin) {
      active.push_back(c);
      gap.push_back(z);
    }
  }
  const VecX old = impulses;
  impulses.setZero();
  const int k = static_cast<int>(active.size());
  info.active_rows = k;
  if (k == 0) return 0;

  MatX jn(k, m), jt(2 * k, m);
  VecX b(k), lam_n(k), lam_t(2 * k);
  for (int i = 0; i < k; ++i) {
    const int c = active[i];
    jn.row(i) = surface_rows_.row(3 * c + 2);
    jt.row(2 * i) = surface_rows_.row(3 * c);
    jt.row(2 * i + 1) = surface_rows_.row(3 * c + 1);
    b[i] = gap[i] >= 0.0 ? -gap[i] / h : -cfg.stabilization * gap[i] / h;
    lam_n[i] = std::max(old[3 * c + 2], 0.0);  // warm start by node id
    lam_t.segment<2>(2 * i) = old.segment<2>(3 * c);
  }
  const VecX v_free = v;
  const double eps = tol;  // smoothing of |v_t|: sticking nodes creep at most ~eps
  // Constant within the step: E^T = L^-1 J_n^T (the LDP's constraint matrix). The velocity
  // response to the impulses, A^-1 J^T lambda, is two triangular solves per stagger: forming
  // A^-1 J_n^T and A^-1 J_t^T once instead takes 3k right-hand sides (k candidates; ~130k
  // multiply-adds on the quadruped) for per-stagger products no cheaper than the solves.
  MatX g(m + 1, k);
  g.topRows(m) = a_llt.matrixL().solve(jn.transpose());
  VecX response(m);
  auto velocity_after = [&](const MatX& j, const VecX& lam) -> const VecX& {
    if (fast) {
      // Only loaded nodes carry impulses (~7 of 64 candidates on a walker): J^T lambda from
      // their rows, not a product over every row.
      response.setZero();
      for (Eigen::Index i = 0; i < lam.size(); ++i)
        if (lam[i] != 0.0) response.noalias() += lam[i] * j.row(i).transpose();
    } else {
      response.noalias() = j.transpose() * lam;
    }
    a_llt.solveInPlace(response);
    response += v_free;
    return response;
  };

  VecX x_ldp(m), lam_ldp(k), row_gap(k);  // per-stagger buffers (row_gap: a J_n product)
  auto normal_solve = [&](const VecX& v_prime) {
    // With A = L L^T and x = L^T (v - v'), the normal problem is the least-distance programme
    // min |x| s.t. J_n L^-T x >= b - J_n v', solved exactly by NNLS (Lawson & Hanson), whose
    // active set copes with the redundant rows; the multipliers are the normal impulses.
    ++info.normal_iterations;
    ScopedTimer timer(cfg.profile ? &info.time_normal : nullptr);
    row_gap.noalias() = jn * v_prime;
    g.row(m) = (b - row_gap).transpose();
    lam_ldp = lam_n;  // warm start: last stagger's (or step's) loaded nodes
    bool nnls_ok = true;
    if (least_distance(g, x_ldp, lam_ldp, nnls_ok, how, ws.nnls)) {
      a_llt.matrixU().solveInPlace(x_ldp);
      v = v_prime + x_ldp;
      lam_n = lam_ldp;
    } else {
      v = v_prime;  // unreachable for a ground plane (moving up is always feasible)
      lam_n.setZero();
      nnls_ok = false;
    }
    // The LDP's answer must be feasible: every candidate ends on or above its bound.
    if (nnls_ok) {
      row_gap.noalias() = jn * v;
      const double worst = (b - row_gap).maxCoeff();
      if (worst > tol) nnls_ok = false;
    }
    if (!nnls_ok) info.contact_converged = false;
  };

  VecX vc_prev, vc, weight(k), v_prev = v, dv_stagger(m), v_second(m);
  Eigen::Vector2d ut2;
  auto contact_velocities = [&](VecX& out) {
    out.head(k).noalias() = jn * v;
    out.tail(2 * k).noalias() = jt * v;
  };
  if (!fast) {  // the reference compares all 3k contact velocities stagger to stagger
    vc_prev.resize(3 * k);
    vc.resize(3 * k);
    contact_velocities(vc_prev);
  }
  MatX hess(m, m), wjt(2 * k, m);
  std::vector<int> loaded, dual_loaded;
  loaded.reserve(k);
  MatX y_l, delassus_l, dual_sys;
  VecX rhs_l;
  Eigen::LLT<MatX> dual_llt;
  int stagger = 0;
  bool converged = false;
  StaggerExtrapolation extrapolation(lam_n, lam_t);
  bool after_jump = false;  // the stagger after a jump may not declare convergence
  for (; stagger < cfg.max_stagger_iterations; ++stagger) {
    // --- Normal problem with the friction impulses held fixed.
    normal_solve(velocity_after(jt, lam_t));
    // --- Friction problem with the normal impulses held fixed.
    v_second = velocity_after(jn, lam_n);
    ++info.friction_iterations;
    ScopedTimer timer(cfg.profile ? &info.time_friction : nullptr);
    {
      // One reweighted least-squares step on the smoothed, strictly convex
      //   phi(v) = 1/2 |v - v''|_A^2 + sum_i c_i sqrt(|J_t,i v|^2 + eps^2),  c_i = mu lambda_n,i:
      // v minimises phi's quadratic majoriser at the current velocities, so phi decreases and
      // the friction impulses -c_i J_t,i v / |J_t,i v|_eps stay inside the Coulomb discs. The
      // stagger loop iterates to the joint fixed point. (Measured on the quadruped: staggering
      // converges linearly at a rate near 0.95 per stagger; solving this half to convergence
      // by Newton's method, or Anderson-accelerating the stagger map, made it oscillate
      // instead: the slow part is the normal-friction coupling, a sliding node's load creeping
      // up stagger by stagger, which the guarded Aitken jump above shortens.)
      // Only loaded nodes (lambda_n > 0) carry friction: the others have zero weight.
      loaded.clear();
      for (int i = 0; i < k; ++i)
        if (lam_n[i] > 0.0 && mu > 0.0) loaded.push_back(i);
      const int nl = static_cast<int>(loaded.size());
      lam_t.setZero();
      if (nl == 0) {
        v = v_second;
      } else {
        for (int l = 0; l < nl; ++l) {
          const int i = loaded[l];
          const Eigen::Vector2d ut = jt.middleRows(2 * i, 2) * v;
          weight[l] = mu * lam_n[i] / std::sqrt(ut.squaredNorm() + eps * eps);
        }
        // The step solves (A + J_l^T W J_l) v = A v'' (J_l: the loaded nodes' tangent rows,
        // W their weights). With fewer rows than coordinates (2 nl < M + 6: a walker stands
        // on ~7 nodes) it is solved in the rows' space instead (Woodbury):
        //   v = v'' - A^-1 J_l^T (W^-1 + J_l A^-1 J_l^T)^-1 J_l v'',
        // where J_l A^-1 J_l^T = Y^T Y, Y = L^-1 J_l^T, changes only with the loaded set (which
        // does change in most staggers: the saving is the factorisation, (2 nl)^2 instead of a
        // rank update and an (M + 6)^2 one).
        bool solved = false;
        if (fast && 2 * nl < m) {
          if (loaded != dual_loaded) {
            y_l.resize(m, 2 * nl);
            for (int l = 0; l < nl; ++l)
              y_l.middleCols(2 * l, 2) = jt.middleRows(2 * loaded[l], 2).transpose();
            a_llt.matrixL().solveInPlace(y_l);
            delassus_l.noalias() = y_l.transpose() * y_l;
            dual_loaded = loaded;
          }
          dual_sys = delassus_l;
          rhs_l.resize(2 * nl);
          for (int l = 0; l < nl; ++l) {
            dual_sys.diagonal().segment<2>(2 * l).array() += 1.0 / weight[l];
            rhs_l.segment<2>(2 * l).noalias() = jt.middleRows(2 * loaded[l], 2) * v_second;
          }
          dual_llt.compute(dual_sys);
          if (dual_llt.info() == Eigen::Success) {
            dual_llt.solveInPlace(rhs_l);
            response.noalias() = y_l * rhs_l;
            a_llt.matrixU().solveInPlace(response);
            v = v_second - response;
            solved = v.allFinite();
          }
        }
        if (!solved) {
          for (int l = 0; l < nl; ++l)  // sqrt(w_i) J_t,i stacked: one rank update
            wjt.middleRows(2 * l, 2) = std::sqrt(weight[l]) * jt.middleRows(2 * loaded[l], 2);
          hess = a;
          hess.selfadjointView<Eigen::Lower>().rankUpdate(wjt.topRows(2 * nl).transpose());
          v = hess.selfadjointView<Eigen::Lower>().llt().solve(a * v_second);
        }
        for (int l = 0; l < nl; ++l) {
          const int i = loaded[l];
          ut2.noalias() = jt.middleRows(2 * i, 2) * v;  // into a fixed-size vector: no heap
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
      row_gap.noalias() = jn * dv_stagger;
      change = row_gap.cwiseAbs().maxCoeff();
      for (int i = 0; i < k; ++i)
        if (lam_n[i] > 0.0) {
          ut2.noalias() = jt.middleRows(2 * i, 2) * dv_stagger;
          change = std::max(change, ut2.cwiseAbs().maxCoeff());
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
      if (f > 0.0) {
        lam_t += f * extrapolation.friction_change();
        extrapolation.jumped(lam_t);
        after_jump = true;
      }
    }
  }
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
// quadruped's feet sink 6 cm.) It is the fast approximate option; staggered projection is the
// accurate one.
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
