// The implicit step in the reduced coordinates: implicit Euler on
//
//   v - v_n = h (f_ext + f_e(q_n + h v) - D v + f_drag + f_contact),   q_{n+1} = q_n + h v,
//
// i.e. the minimiser of the incremental potential
//
//   Phi(v) = 1/2 |v - v_n|^2 - h f_ext.v + Psi(q_n + h v) + h alpha/2 |v|^2
//            + h beta/2 v_e^T K_0 v_e - h f_d.v - h/2 (v - v_n)^T J_d (v - v_n),
//
// (identity reduced mass; K_0 the rest stiffness for Rayleigh damping; drag linearised in v
// at the start of the step), followed by the contact projection.
#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>

#include "dense_kernels.h"
#include "reduced_model.h"

namespace softrom {

namespace {

// The penalty step's refinement of S^-1 r is kept while its residual is at most this fraction
// of r; beyond it the Newton step is solved exactly (step_reference's penalty branch).
constexpr double kRefinementResidual = 0.1;

// The quasi-Newton direction dv = -H g, H the m x m inverse estimate (column-major).
void newton_direction(const MatX& h_inv, const VecX& g, VecX& dv) {
  const Eigen::Index m = g.size();
  dv.resize(m);
  kernels::cols_times(h_inv.data(), m, m, g.data(), dv.data());
  dv = -dv;
}

}  // namespace

StepInputs ReducedModel::inputs() const {
  StepInputs in{config, control_basis_, nullptr};
  if (uses_fast_step(config)) in.rest_newton_inverse = rest_newton_inverse(config);
  return in;
}

std::shared_ptr<const MatX> ReducedModel::rest_newton_inverse(const ReducedConfig& cfg) const {
  std::lock_guard<std::mutex> lock(rest_newton_mutex_);
  RestNewtonCache& cache = rest_newton_cache_;
  // (== on the settings: they are finite, and a -0.0 for 0.0 forms the same A_0.)
  if (cache.formed && cache.dt == cfg.dt && cache.damping_alpha == cfg.damping_alpha &&
      cache.damping_beta == cfg.damping_beta)
    return cache.inverse;
  const Eigen::Index m = basis_cols_;
  const int md = elastic_dim();
  const double h = cfg.dt;
  MatX a = MatX::Identity(m, m);
  a.bottomRightCorner(md, md) += (h * h + h * cfg.damping_beta) * k_rest_;
  if (cfg.damping_alpha > 0.0) a.diagonal().array() += h * cfg.damping_alpha;
  Eigen::LLT<MatX> llt(a);
  // K_0 is positive semi-definite, so A_0 is positive definite for any valid setting.
  std::shared_ptr<const MatX> inverse;
  if (llt.info() == Eigen::Success)
    inverse = std::make_shared<const MatX>(llt.solve(MatX::Identity(m, m)));
  cache = {true, cfg.dt, cfg.damping_alpha, cfg.damping_beta, inverse};
  return inverse;
}

void ReducedModel::external_forces(const StepInputs& in, const double* fc, VecX& f_ext) const {
  // B_r^T M g: uniform gravity only loads the translation columns, as the rotation (about
  // the centre of mass) and deformation columns are mass-orthogonal to them. Actuation
  // f_r = B_c f_c acts on the deformation coordinates, never on the rigid ones.
  const Eigen::Index m = basis_cols_;
  const int nd = deformation_dim();
  f_ext.setZero(m);
  f_ext.head<3>() = std::sqrt(total_mass_) * in.config.gravity;
  const Eigen::Index c = in.control_basis.cols();
  if (fc != nullptr && c > 0)
    f_ext.tail(nd).noalias() += in.control_basis * Eigen::Map<const VecX>(fc, c);
}

// The loads of a step that do not depend on the new velocity: f_ext (gravity, actuation) and,
// when swimming, the drag and its velocity Jacobian at the start of the step.
// `jacobian`: also form J_d as a matrix (the fast solver uses its factor W alone, and forms
// J_d only when a Newton matrix needs it).
void ReducedModel::step_loads(const StepInputs& in, const ReducedState& s, const double* fc,
                              bool jacobian, Workspace& ws, StepInfo& info) const {
  external_forces(in, fc, ws.f_ext);
  ws.drag_cols = 0;
  ws.drag_jacobian_formed = false;
  if (in.config.fluid_density > 0.0) {
    ScopedTimer timer(in.config.profile ? &info.time_drag : nullptr);
    if (in.config.solver == Solver::Fast) {
      drag_fast(in.config, s.q, s.qdot, ws);
      if (jacobian) drag_jacobian(ws.drag_w, ws.drag_cols, ws.j_drag);
    } else {
      drag(in.config, s.q, s.qdot, ws.f_drag, jacobian ? &ws.j_drag : nullptr, ws.drag_w,
           ws.drag_cols);
    }
    ws.drag_jacobian_formed = jacobian;
  }
}

StepInfo ReducedModel::step(const StepInputs& in, ReducedState& s, const double* fc,
                            Workspace& ws) const {
  assert(ws.lender == this && "a Workspace serves the model that lent it (reduced_model.h)");
  ws.ground_rows_ready = false;
  if (in.config.frame == Frame::Floating) return step_floating(in, s, fc, ws);
  if (uses_fast_step(in.config)) return step_fast(in, s, fc, ws);
  return step_reference(in, s, fc, ws);
}

// Newton's method on the residual, the stiffness rebuilt at every iteration: the reference
// solver, which the fast step is checked against, and every solver's step with penalty contact
// (with the fast kernels, and the stiffness as a chord, when solver = fast). Penalty contact,
// whose regularised friction switches sign over a few mm/s, gets a backtracking line search on
// |r|: without it Newton cycled, and 70-100% of walking steps ended at the iteration cap.
StepInfo ReducedModel::step_reference(const StepInputs& in, ReducedState& s, const double* fc,
                                      Workspace& ws) const {
  const ReducedConfig& cfg = in.config;
  StepInfo info;
  const double h = cfg.dt;
  const Eigen::Index m = basis_cols_;
  const int md = elastic_dim();
  const double sqrt_m = std::sqrt(total_mass_);
  const bool fast_kernels = cfg.solver == Solver::Fast;

  const VecX& f_ext = ws.f_ext;
  const bool swim = cfg.fluid_density > 0.0;
  step_loads(in, s, fc, true, ws, info);
  ScopedTimer dyn_timer(cfg.profile ? &info.time_dynamics : nullptr);

  // Every buffer is the workspace's, so the step allocates nothing once the worker has seen
  // its sizes (the reference kernel, elastic_reference, still allocates: it is kept as #8
  // found it, the yardstick the fast kernels are measured against).
  VecX& v = ws.v;
  v = s.qdot;
  VecX& f_el = ws.f_el;
  VecX& r = ws.r;
  VecX& dv = ws.dv;
  VecX& qe = ws.ref_qe;
  MatX& k_el = ws.k_el;
  MatX& a = ws.a;
  r.resize(m);
  Eigen::LDLT<MatX>& ldlt = ws.ref_ldlt;
  info.converged = false;
  const bool penalty = cfg.contact == ContactModel::Penalty;
  // The implicit-Euler residual at velocity w, given the elastic force f_e and (with penalty
  // contact) the penalty force f_p at q_n + h w (K_0 acting on w's elastic coordinates):
  //   r(w) = w - v_n - h (f_ext + f_e + f_drag + J_d (w - v_n) + f_p) + h alpha w + h beta K_0 w.
  // (The products go through scratch, as Eigen evaluates them into a temporary: the same
  // sums, without the heap.)
  VecX& prod = ws.ref_prod;
  auto residual = [&](const VecX& w, const VecX& f_e, const VecX& f_p, VecX& out) {
    out = w - s.qdot;
    out -= h * f_ext;
    out.tail(md) -= h * f_e;
    if (cfg.damping_alpha > 0.0) out += h * cfg.damping_alpha * w;
    if (cfg.damping_beta > 0.0) {
      prod.noalias() = (h * cfg.damping_beta) * (k_rest_ * w.tail(md));
      out.tail(md) += prod;
    }
    if (swim) {
      ws.ref_dw = w - s.qdot;
      prod.noalias() = ws.j_drag * ws.ref_dw;
      out -= h * (ws.f_drag + prod);
    }
    if (penalty) out -= h * f_p;
  };
  // |r(w)| for the penalty line search (forces only: no stiffness, no penalty Jacobian).
  VecX& r_trial = ws.ref_r_trial;
  VecX& f_trial = ws.ref_f_trial;
  VecX& f_pen_trial = ws.ref_f_pen_trial;
  VecX& qe_trial = ws.ref_qe_trial;
  VecX& v_trial = ws.v_trial;
  auto residual_norm = [&](const VecX& w) {
    qe_trial = s.q.tail(md) + h * w.tail(md);
    if (fast_kernels) {
      elastic_energy_force(qe_trial, f_trial, ws);
    } else {
      elastic_reference(qe_trial, false, nullptr, &f_trial, nullptr);
    }
    ws.ref_q = s.q + h * w;
    penalty_contacts(cfg, ws.ref_q, w, f_pen_trial, nullptr, ws);
    residual(w, f_trial, f_pen_trial, r_trial);
    return r_trial.norm();
  };
  // Penalty contact's fast solver keeps K_r from the first iterate (a chord) and evaluates it
  // again only when the iteration stalls, by step_fast's test: a step no smaller than half the
  // last. Within a step K_r barely moves; the penalty forces, whose Jacobian is formed at every
  // iterate, are what Newton has to resolve. Measured on walking gaits: the same Newton
  // iterations per step, 1.4-2.9 stiffness evaluations a step where exact Newton made 5.4-7.4
  // (one per iteration), the step 1.2-1.7x faster (benchmarks/PROFILE.md, session 48).
  bool refresh_stiffness = true;
  double last_step = std::numeric_limits<double>::infinity();
  // True when v is the line search's accepted trial point, whose elastic force f_trial is
  // then f_e at v (q_e is the same sum again), so it is not evaluated twice. (The penalty
  // force is: the trial formed it without its Jacobian.)
  bool at_trial = false;
  for (int it = 0; it < cfg.max_newton_iterations; ++it) {
    qe = s.q.tail(md) + h * v.tail(md);
    if (at_trial) f_el.swap(f_trial);
    // The exact reduced Hessian: I dominates A = I + dt^2 K_r + ..., so A stays positive
    // definite unless an element is crushed; only then is K_r projected (below), an
    // (M + 3)-square eigen decomposition instead of one 9 x 9 decomposition per element.
    if (!fast_kernels) {
      elastic_reference(qe, false, nullptr, at_trial ? nullptr : &f_el, &k_el);
      ++info.stiffness_evaluations;
    } else {
      if (!at_trial) elastic_energy_force(qe, f_el, ws);
      if (refresh_stiffness) {
        elastic_stiffness_fast(qe, k_el, ws);
        ++info.stiffness_evaluations;
      }
    }
    if (penalty) {
      ws.ref_q = s.q + h * v;
      penalty_contacts(cfg, ws.ref_q, v, ws.f_pen, &ws.j_pen, ws);
    }
    residual(v, f_el, ws.f_pen, r);
    // A = dr/dv = I + h^2 K_r + h alpha I + h beta K_0 - h J_d - h J_pen.
    a.setIdentity(m, m);
    a.bottomRightCorner(md, md) += (h * h) * k_el;
    if (cfg.damping_alpha > 0.0) a.diagonal().array() += h * cfg.damping_alpha;
    if (cfg.damping_beta > 0.0) a.bottomRightCorner(md, md) += (h * cfg.damping_beta) * k_rest_;
    if (swim) a -= h * ws.j_drag;
    if (penalty) a -= h * ws.j_pen;
    ldlt.compute(a);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive() ||
        (ldlt.vectorD().array() <= 0.0).any()) {
      // (Only where an element is crushed: this allocates, and it is rare.)
      Eigen::SelfAdjointEigenSolver<MatX> es(k_el);
      const MatX k_psd = es.eigenvectors() * es.eigenvalues().cwiseMax(0.0).asDiagonal() *
                         es.eigenvectors().transpose();
      a.bottomRightCorner(md, md) += (h * h) * (k_psd - k_el);
      ldlt.compute(a);
    }
    // With penalty contact the friction's coupling to the normal force C makes A = S - h C
    // unsymmetric (S: A's symmetric part, factored above). Left out, Newton took 15-24 % more
    // iterations on walking gaits. The reference solver factors A by LU; the fast solver takes
    // one step of refinement on S's factor, d = S^-1 (r + h C S^-1 r), with C applied through
    // its rows: as few iterations as the exact solve, where forming C and its LU made the step
    // 0.71-0.82x as fast (benchmarks/PROFILE.md, session 50).
    // The refinement is the first term of a Neumann series in h S^-1 C, so it holds only while
    // that is small. On a ground some thousand times stiffer than the default it is not
    // (spectral radius 0.7-1.4): the refined step was far off, the line search failed, and
    // Newton drifted to velocities of tens of m/s. So the refined step's own residual,
    // (S - h C) d1 - r = h C (d0 - d1), is checked (one more product with C's rows), and where
    // it is not small against r the step is solved exactly, by LU as the reference solver does.
    // One exact path: the reference solver's, and the fast one's where its refinement fails.
    bool exact_coupling = penalty && !fast_kernels;
    if (!exact_coupling) {
      dv = r;
      ldlt.solveInPlace(dv);
      // (Not on the iteration that certifies the step: the certificate stays what it was
      // before the coupling was taken, the symmetric solve's step S^-1 r below the tolerance,
      // a bound on the residual r through S.)
      if (penalty && ws.pen_loaded > 0 &&
          dv.cwiseAbs().maxCoeff() / sqrt_m >= cfg.newton_tolerance) {
        penalty_coupling_times(dv, ws.pen_cx, ws);
        ws.pen_rhs = r;
        ws.pen_rhs.noalias() += h * ws.pen_cx;
        ldlt.solveInPlace(ws.pen_rhs);
        dv -= ws.pen_rhs;  // d0 - d1
        penalty_coupling_times(dv, ws.pen_cx, ws);
        exact_coupling = h * ws.pen_cx.norm() > kRefinementResidual * r.norm();
        if (exact_coupling) {
          penalty_coupling_matrix(ws, ws.j_pen_coupling);
        } else {
          dv.swap(ws.pen_rhs);
        }
      }
    }
    if (exact_coupling) {
      a -= h * ws.j_pen_coupling;
      ws.ref_lu.compute(a);
      dv.noalias() = ws.ref_lu.solve(r);
    }
    dv = -dv;
    info.newton_iterations = it + 1;
    if (!dv.allFinite()) {
      info.diverged = true;
      return info;
    }
    const double step_norm = dv.cwiseAbs().maxCoeff() / sqrt_m;
    refresh_stiffness = !(fast_kernels && penalty) || step_norm > 0.5 * last_step;
    last_step = step_norm;
    double t = 1.0;
    at_trial = false;
    if (penalty && step_norm >= cfg.newton_tolerance) {
      const double r0 = r.norm();
      for (int ls = 0; ls < 8; ++ls) {
        v_trial = v + t * dv;
        if (residual_norm(v_trial) <= (1.0 - 1e-4 * t) * r0) {
          at_trial = true;
          break;
        }
        t *= 0.5;
      }
    }
    if (at_trial) {
      v.swap(v_trial);
    } else {
      v += t * dv;
    }
    if (step_norm < cfg.newton_tolerance) {
      info.converged = true;
      break;
    }
  }
  Eigen::LLT<MatX> a_llt;
  if (cfg.contact == ContactModel::Staggered) a_llt.compute(a);
  dyn_timer.stop();
  finish_step(in, s, v, a, a_llt, ws, info);
  return info;
}

// Quasi-Newton on Phi: the first matrix is A_0 = I + (h^2 + h beta) K_0 + h alpha I, the
// implicit matrix at rest without drag (it needs no stiffness evaluation and is the same for
// every step with the same dt and damping), improved by BFGS updates of its inverse from the
// gradients the line search computes anyway. The stiffness K_r(q) is evaluated only when the
// iteration stalls (a step no smaller than half the last), and then replaces K_0. An Armijo
// backtracking line search on Phi makes every iteration descend; the step is certified
// (info.converged) by the same test as the reference: max |dv| / sqrt(m) below
// newton_tolerance.
StepInfo ReducedModel::step_fast(const StepInputs& in, ReducedState& s, const double* fc,
                                 Workspace& ws) const {
  const Eigen::Index m = basis_cols_;
  // Without A_0^-1 (inputs() found A_0 not positive definite, which a PSD K_0 rules out but
  // round-off might not), the exact Newton of the reference, on the fast kernels. A guard
  // only: no setting reaches it on the shipped robots (A_0 depends on dt, damping_alpha and
  // damping_beta alone; 20,000 of them over their whole range, none did), and an A_0 that
  // overflows factors into NaN rather than failing, so that step reports divergence.
  if (!in.rest_newton_inverse) return step_reference(in, s, fc, ws);
  const ReducedConfig& cfg = in.config;
  StepInfo info;
  const double h = cfg.dt;
  const int md = elastic_dim();
  const double sqrt_m = std::sqrt(total_mass_);
  const bool swim = cfg.fluid_density > 0.0;

  const VecX& f_ext = ws.f_ext;
  step_loads(in, s, fc, false, ws, info);
  ScopedTimer dyn_timer(cfg.profile ? &info.time_dynamics : nullptr);

  // A = I + h^2 K + h beta K_0 + h alpha I - h J_d for a stiffness K. The quasi-Newton solve
  // starts from the inverse of A_0 (K = K_0, without the drag term): only a preconditioner, it
  // is formed once per setting of dt and damping (StepInputs), and the potential applies
  // J_d = -W W^T as two thin products, never forming it. The Newton matrices that must be
  // exact (a refresh, the contact metric) include J_d.
  MatX& a = ws.a;
  auto build_a = [&](const MatX& k) {
    a.setIdentity(m, m);
    a.bottomRightCorner(md, md) += (h * h) * k + (h * cfg.damping_beta) * k_rest_;
    if (cfg.damping_alpha > 0.0) a.diagonal().array() += h * cfg.damping_alpha;
    if (swim) {
      if (!ws.drag_jacobian_formed) {
        drag_jacobian(ws.drag_w, ws.drag_cols, ws.j_drag);
        ws.drag_jacobian_formed = true;
      }
      a -= h * ws.j_drag;
    }
  };
  // The factor of A is formed by refresh() below, the only place that needs it (every step
  // that can meet the ground ends with one; a step without one has no contact candidates, so
  // the contact solve does not read it).
  Eigen::LLT<MatX>& a_llt = ws.a_llt;
  MatX& h_inv = ws.h_inv;
  h_inv = *in.rest_newton_inverse;

  VecX& tmp_e = ws.tmp_e;
  tmp_e.resize(md);
  // Phi(v) and its gradient (the reference's residual). `at_start`: v is the step's starting
  // velocity v_n, where the drag's correction J_d (v - v_n) is zero and not computed.
  auto potential = [&](const VecX& v, VecX& grad, bool at_start) -> double {
    tmp_e = s.q.tail(md) + h * v.tail(md);
    const double psi = elastic_energy_force(tmp_e, ws.f_el, ws);
    grad = v - s.qdot;
    double phi = 0.5 * grad.squaredNorm() - h * f_ext.dot(v) + psi;
    if (swim) {
      // J_d (v - v_n) = -W (W^T (v - v_n)), W (drag_fast's) with its rows padded to mp.
      const Eigen::Index mp = ws.drag_w.rows(), nw = ws.drag_cols;
      if (at_start) {  // (the products' sums of +0 terms, without the pass over W)
        ws.drag_wg.setZero(nw);
        ws.drag_wwg.setZero(mp);
      } else {
        ws.drag_pad.setZero(mp);
        ws.drag_pad.head(m) = grad;
        ws.drag_wg.resize(nw);
        ws.drag_wwg.resize(mp);
        kernels::cols_dot_times(ws.drag_w.data(), mp, nw, ws.drag_pad.data(), ws.drag_wg.data(),
                                ws.drag_wwg.data());
      }
      phi -= h * ws.f_drag.dot(v) - 0.5 * h * ws.drag_wg.squaredNorm();
      grad -= h * ws.f_drag;
      grad += h * ws.drag_wwg.head(m);
    }
    grad -= h * f_ext;
    grad.tail(md) -= h * ws.f_el;
    if (cfg.damping_alpha > 0.0) {
      phi += 0.5 * h * cfg.damping_alpha * v.squaredNorm();
      grad += h * cfg.damping_alpha * v;
    }
    if (cfg.damping_beta > 0.0) {
      kernels::cols_times(k_rest_.data(), md, md, v.data() + (m - md), tmp_e.data());
      phi += 0.5 * h * cfg.damping_beta * v.tail(md).dot(tmp_e);
      grad.tail(md) += h * cfg.damping_beta * tmp_e;
    }
    return phi;
  };

  auto refresh = [&](const VecX& v, bool restart_inverse) -> bool {
    // Replace K_0 by the stiffness at the current iterate (projected if A would not be
    // positive definite), and restart the inverse from its exact inverse (not needed for
    // the contact metric at the step's end, which uses the factor alone).
    tmp_e = s.q.tail(md) + h * v.tail(md);
    elastic_stiffness_fast(tmp_e, ws.k_el, ws);
    ++info.stiffness_evaluations;
    build_a(ws.k_el);
    a_llt.compute(a);
    if (a_llt.info() != Eigen::Success) {
      Eigen::SelfAdjointEigenSolver<MatX> es(ws.k_el);
      build_a(es.eigenvectors() * es.eigenvalues().cwiseMax(0.0).asDiagonal() *
              es.eigenvectors().transpose());
      a_llt.compute(a);
      if (a_llt.info() != Eigen::Success) return false;
    }
    if (restart_inverse) h_inv = a_llt.solve(MatX::Identity(m, m));
    return true;
  };

  VecX& v = ws.v;
  v = s.qdot;
  VecX& g = ws.g;
  VecX& g_trial = ws.g_trial;
  VecX& v_trial = ws.v_trial;
  VecX& dv = ws.dv;
  VecX& sv = ws.s;
  VecX& y = ws.y;
  VecX& hy = ws.hy;
  double phi = potential(v, g, true);
  double prev_norm = std::numeric_limits<double>::infinity();
  bool refreshed = false;
  info.converged = false;
  constexpr double kArmijo = 1e-4;
  constexpr double kRoundoff = 1e-13;
  for (int it = 0; it < cfg.max_newton_iterations; ++it) {
    newton_direction(h_inv, g, dv);
    info.newton_iterations = it + 1;
    if (!dv.allFinite() || !std::isfinite(phi)) {
      info.diverged = true;
      return info;
    }
    const double step_norm = dv.cwiseAbs().maxCoeff() / sqrt_m;
    if (step_norm < cfg.newton_tolerance) {
      v += dv;
      info.converged = true;
      break;
    }
    if (it >= 1 && step_norm > 0.5 * prev_norm && !refreshed) {
      // Linear convergence too slow for A_0: build the real stiffness once.
      refreshed = true;
      if (!refresh(v, true)) {
        info.diverged = true;
        return info;
      }
      newton_direction(h_inv, g, dv);
    }
    prev_norm = step_norm;
    // Armijo backtracking; a rise within round-off of Phi counts as no rise.
    const double slope = g.dot(dv);
    double t = 1.0, phi_trial = 0.0;
    for (int ls = 0; ls < 30; ++ls) {
      v_trial = v + t * dv;
      phi_trial = potential(v_trial, g_trial, false);
      if (phi_trial <= phi + kArmijo * t * slope + kRoundoff * std::abs(phi)) break;
      t *= 0.5;
    }
    sv = v_trial - v;
    y = g_trial - g;
    const double sy = sv.dot(y);
    if (sy > 1e-12 * sv.norm() * y.norm()) {
      // BFGS update of the inverse: H+ = (I - r s y^T) H (I - r y s^T) + r s s^T.
      const double rho = 1.0 / sy;
      hy.resize(m);
      kernels::cols_times(h_inv.data(), m, m, y.data(), hy.data());
      const double yhy = y.dot(hy);
      // Column by column: H+_(:,j) = H_(:,j) + (c s_j - rho hy_j) s - rho s_j hy, c = rho^2
      // y^T H y + rho (H symmetric, so H y = H^T y); Eigen's two outer products cost 20x more.
      const double c = rho * rho * yhy + rho;
      for (Eigen::Index j = 0; j < m; ++j)
        h_inv.col(j) += (c * sv[j] - rho * hy[j]) * sv - (rho * sv[j]) * hy;
    }
    v.swap(v_trial);
    g.swap(g_trial);
    phi = phi_trial;
  }
  // The contact projection uses A as its metric (the velocity response to an impulse), so it
  // needs the stiffness where the step ends, as the reference's last Newton matrix has it.
  // Measured one step at a time against a tightly converged reference on a walking
  // quadruped: with A_0 the velocity error is 40x the reference's own (7e-3 vs 1.8e-4 m/s
  // RMS), with the stiffness at the step's start 3.5x, with the stiffness at its end equal.
  // So a step with contact candidates builds K_r once, at the end; other steps never do.
  if (cfg.contact == ContactModel::Staggered && near_ground(cfg, s.q, v, ws)) {
    if (!refresh(v, false)) {
      info.diverged = true;
      return info;
    }
  }
  dyn_timer.stop();
  finish_step(in, s, v, a, a_llt, ws, info);
  return info;
}

// True when a surface node is a contact candidate (contact_candidate) at q and v.
bool ReducedModel::near_ground(const ReducedConfig& cfg, const VecX& q, const VecX& v,
                               Workspace& ws) const {
  // (Only the fast step tests this: N q and N v by the column-major kernel, 0.07 M instructions
  // per quadruped step fewer than Eigen's row-major product, by callgrind; both in one pass
  // over N, which is ~0.2 MB on the quadruped: the same sums as two passes, read once.)
  VecX& z = ws.ground_z;
  VecX& vn = ws.ground_vn;
  const Eigen::Index ns = normal_cols_.rows();
  z.resize(ns);
  vn.resize(ns);
  kernels::cols_times_pair(normal_cols_.data(), ns, normal_cols_.cols(), q.data(), v.data(),
                           z.data(), vn.data());
  ws.ground_rows_ready = true;  // for solve_contacts, at the same q and v
  for (Eigen::Index c = 0; c < z.size(); ++c)
    if (contact_candidate(cfg, ground_gap(cfg, c, z[c]), vn[c])) return true;
  return false;
}

// Contact projection, divergence check, and the state update. Impulses are solved into a copy:
// a step that diverges leaves the whole state as it was.
bool ReducedModel::finish_step(const StepInputs& in, ReducedState& s, VecX& v, const MatX& a,
                               const Eigen::LLT<MatX>& a_llt, Workspace& ws,
                               StepInfo& info) const {
  const ReducedConfig& cfg = in.config;
  const double h = cfg.dt;
  const double sqrt_m = std::sqrt(total_mass_);
  // Without the staggered projection the step neither reads nor writes the impulses (3 per
  // surface node: 1,350 on the cross swimmer, a copy and two passes that cost a twentieth of
  // its fast step), and it has no contacts.
  const bool staggered = cfg.contact == ContactModel::Staggered;
  VecX& impulses = ws.impulses_next;
  if (staggered) {
    impulses = s.impulses;
    info.stagger_iterations = solve_contacts(cfg, s.q, a, a_llt, v, impulses, ws, info);
  }
  VecX& q_next = ws.q_next;
  q_next = s.q + h * v;
  // Divergence: non-finite state or RMS node speed beyond any physical meaning.
  // (info.diverged may come from the contact solve: a normal problem it could not solve.)
  if (info.diverged || !v.allFinite() || !q_next.allFinite() ||
      (staggered && !impulses.allFinite()) || v.norm() / sqrt_m > cfg.max_speed) {
    info.diverged = true;
    return false;  // the state keeps its last good value
  }
  s.q.swap(q_next);
  s.qdot = v;
  if (staggered) {
    for (Eigen::Index c = 0; c < impulses.size() / 3; ++c)
      if (impulses[3 * c + 2] > 0.0) ++info.contacts;
    s.impulses.swap(impulses);
  }
  return true;
}

}  // namespace softrom
