// The floating frame's implicit step (docs/FLOATING_FRAME.md; kinematics in floating_frame.h).
//
// State q = (sqrt(m) (c - c_0), theta, z), qdot = (sqrt(m) u, omega, w), R = exp([theta]x).
// Momentum-form implicit Euler, with c' = c + h u', R' = R exp(h omega'), z' = z + h w':
//
//   (1 + h alpha) u'  = u + h g                                                  (translation)
//   (1 + h alpha) Pi' = exp(-h omega') Pi                                        (rotation)
//   (1 + h alpha) p'  = p + h (dT/dz' + f_e(z') - beta K_0 w' + Q_a(z'))         (deformation)
//
// with Pi = dT/d omega = I(z) omega + S(z) w the body-frame angular momentum, p = dT/dw =
// S(z)^T omega + w, dT/dz_k = 1/2 omega^T (dI/dz_k) omega + omega^T (dS/dz_k) w, f_e the
// cubature's elastic force on the deformation columns, and Q_a the actuation:
//
//   Q_a(z) = (I - S(z)^T I(z)^-1 S(z)) f,   f = B_c f_c,
//
// the generalised force of the nodal field M R U f that follows the body less the rigid
// rotation that cancels its torque about c (the field an actuator built into the robot
// applies; a bare f on z is internal too but a different field, which spun a slender beam's
// frame at 205 rad/s in the prototype). The rotation line makes the world angular momentum
// R' Pi' = R Pi exactly whatever the internal forces, so in free flight L is kept to the
// Newton tolerance. Mass-proportional damping alpha acts on every node (-alpha m_i v_i: on u,
// Pi and p alike); beta K_0 on the deformation only. Uniform gravity loads c alone.
#include <algorithm>
#include <cassert>
#include <cmath>

#include "reduced_model.h"

namespace softrom {

const char* floating_unsupported(const ReducedConfig& cfg) {
  if (cfg.frame != Frame::Floating) return nullptr;
  if (cfg.contact != ContactModel::None)
    return "frame='floating' simulates free flight only: set contact='none' (ground contact "
           "in the floating frame is not built yet, docs/FLOATING_FRAME.md)";
  if (cfg.fluid_density > 0.0)
    return "frame='floating' simulates free flight only: set fluid_density=0 (drag in the "
           "floating frame is not built yet, docs/FLOATING_FRAME.md)";
  return nullptr;
}

void ReducedModel::floating_residual(const StepInputs& in, const ReducedState& s,
                                     const Vec3& pi0, const VecX& x, bool jacobian,
                                     Workspace& ws) const {
  const ReducedConfig& cfg = in.config;
  const FloatingCoefficients& co = floating_;
  const Eigen::Index nd = deformation_dim();
  const double h = cfg.dt, damp = 1.0 + h * cfg.damping_alpha;
  // Rotation rows are divided by sqrt(m) r_g, which makes them mass-scaled velocities like
  // the deformation rows: one norm serves the line search.
  const double row_scale = 1.0 / (std::sqrt(total_mass_) * co.gyration);
  const Vec3 om = x.head<3>();
  const auto w = x.tail(nd);
  ws.fl_z = s.q.tail(nd) + h * w;
  FloatingBody& body = ws.fl_body;
  body.evaluate(co, ws.fl_z);

  // Elastic force (and stiffness) of the deformation: the cubature's kernels on q_e =
  // (0, 0, 0, z'), the rotation columns held at zero (the frame carries the rotation).
  ws.fl_qe.setZero(nd + 3);
  ws.fl_qe.tail(nd) = ws.fl_z;
  if (cfg.solver == Solver::Fast) {
    elastic_energy_force(ws.fl_qe, ws.fl_fe, ws);
    if (jacobian) elastic_stiffness_fast(ws.fl_qe, ws.fl_k, ws);
  } else {
    elastic_reference(ws.fl_qe, false, nullptr, &ws.fl_fe, jacobian ? &ws.fl_k : nullptr);
  }

  for (int a = 0; a < 3; ++a) ws.fl_yw[a].noalias() = co.y[a] * w;  // (dS/dz_k w)_a
  const Vec3 pi = body.inertia * om + body.s * w;
  const Mat3 turn_back = rotation_matrix(-h * om);
  VecX& r = ws.fl_r;
  r.resize(3 + nd);
  r.head<3>() = (damp * pi - turn_back * pi0) * row_scale;

  // dT/dz_k = 1/2 (tr(D_k) |omega|^2 - omega^T D_k omega) + omega . (dS/dz_k w).
  VecX& g = ws.fl_g;
  g.resize(nd);
  const double om2 = om.squaredNorm();
  for (Eigen::Index k = 0; k < nd; ++k) {
    double quad = 0.0;
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) quad += om[a] * om[b] * body.d[3 * a + b][k];
    g[k] = 0.5 * (body.trace_d(k) * om2 - quad) + om[0] * ws.fl_yw[0][k] +
           om[1] * ws.fl_yw[1][k] + om[2] * ws.fl_yw[2][k];
  }
  // Q_a = f - S^T a, a = I^-1 S f.
  const VecX& f = ws.fl_fa;
  const bool actuated = f.size() == nd && f.any();
  const Mat3 inertia_inv = body.inertia.inverse();
  Vec3 torque_free = Vec3::Zero();  // a
  auto r_w = r.tail(nd);
  r_w = damp * (body.s.transpose() * om + w) - ws.fl_p0;
  r_w -= h * (g + ws.fl_fe.tail(nd));
  if (cfg.damping_beta > 0.0)
    r_w.noalias() += (h * cfg.damping_beta) * (k_rest_.bottomRightCorner(nd, nd) * w);
  if (actuated) {
    torque_free = inertia_inv * (body.s * f);
    r_w -= h * (f - body.s.transpose() * torque_free);
  }
  if (!jacobian) return;

  // The Jacobian d r / d(omega', w'); z' = z + h w' brings a factor h to every z-derivative.
  // E_k = d Pi / dz_k = dI/dz_k omega + dS/dz_k w, which is also d(dT/dz_k)/d omega.
  MatX& e = ws.fl_e;
  e.resize(3, nd);
  for (Eigen::Index k = 0; k < nd; ++k)
    e.col(k) = body.d_inertia(k, om) + Vec3(ws.fl_yw[0][k], ws.fl_yw[1][k], ws.fl_yw[2][k]);
  MatX& jac = ws.fl_jac;
  jac.resize(3 + nd, 3 + nd);
  jac.topLeftCorner<3, 3>() =
      (damp * body.inertia -
       h * turn_back * cross_matrix(pi0) * right_jacobian(-h * om)) * row_scale;
  jac.topRightCorner(3, nd) = (damp * (body.s + h * e)) * row_scale;
  jac.bottomLeftCorner(nd, 3) = damp * body.s.transpose() - h * e.transpose();
  // Y_omega = sum_a omega_a Y_a: d p / dz = Y_omega^T = -Y_omega, d(dT/dz)/dw = Y_omega;
  // d^2 T / dz_k dz_l = |omega|^2 tr(C_kl) - omega^T C_kl omega.
  auto jww = jac.bottomRightCorner(nd, nd);
  jww.setIdentity();
  jww *= damp;
  for (int a = 0; a < 3; ++a) {
    jww.noalias() -= (h * (damp + 1.0) * om[a]) * co.y[a];
    jww.noalias() -= (h * h * om2) * co.c[4 * a];
    for (int b = 0; b < 3; ++b) jww.noalias() += (h * h * om[a] * om[b]) * co.c[3 * a + b];
  }
  jww.noalias() += (h * h) * ws.fl_k.bottomRightCorner(nd, nd);
  if (cfg.damping_beta > 0.0) jww += (h * cfg.damping_beta) * k_rest_.bottomRightCorner(nd, nd);
  if (actuated) {
    // d Q_a / dz_k = -[dS_k^T a + S^T I^-1 (dS_k f - dI_k a)], (dS_k f)_a = (Y_a f)_k,
    // (dS_k^T a)_l = (sum_b a_b Y_b)_(k, l).
    const Vec3& a = torque_free;
    std::array<VecX, 3> yf;
    for (int b = 0; b < 3; ++b) yf[b].noalias() = co.y[b] * f;
    const MatX ya = a[0] * co.y[0] + a[1] * co.y[1] + a[2] * co.y[2];
    const MatX sti = body.s.transpose() * inertia_inv;  // M x 3
    for (Eigen::Index k = 0; k < nd; ++k) {
      const Vec3 inner = Vec3(yf[0][k], yf[1][k], yf[2][k]) - body.d_inertia(k, a);
      // r_w has -h Q_a, so + h^2 (dS_k^T a + S^T I^-1 inner) in column k.
      jww.col(k) += (h * h) * (ya.row(k).transpose() + sti * inner);
    }
  }
}

// The momenta at the step's start (pi0 returned, p_0 and B_c f_c into ws).
static Vec3 floating_start(const FloatingCoefficients& co, const StepInputs& in,
                           const ReducedState& s, const double* fc, Eigen::Index nd,
                           Workspace& ws) {
  ws.fl_fa.setZero(nd);
  const Eigen::Index c = in.control_basis.cols();
  if (fc != nullptr && c > 0) ws.fl_fa.noalias() = in.control_basis * Eigen::Map<const VecX>(fc, c);
  const Vec3 om0 = s.qdot.segment<3>(3);
  const auto w0 = s.qdot.tail(nd);
  ws.fl_body.evaluate(co, s.q.tail(nd));
  ws.fl_p0 = ws.fl_body.s.transpose() * om0 + w0;
  return ws.fl_body.inertia * om0 + ws.fl_body.s * w0;
}

void ReducedModel::floating_residual_for_tests(const StepInputs& in, const ReducedState& s,
                                               const VecX& fc, const VecX& x, MatX& residual,
                                               MatX& jacobian, Workspace& ws) const {
  const Vec3 pi0 = floating_start(floating_, in, s, fc.data(), deformation_dim(), ws);
  floating_residual(in, s, pi0, x, true, ws);
  residual = ws.fl_r;
  jacobian = ws.fl_jac;
}

StepInfo ReducedModel::step_floating(const StepInputs& in, ReducedState& s, const double* fc,
                                     Workspace& ws) const {
  const ReducedConfig& cfg = in.config;
  StepInfo info;
  ScopedTimer timer(cfg.profile ? &info.time_dynamics : nullptr);
  const Eigen::Index nd = deformation_dim();
  const double h = cfg.dt, damp = 1.0 + h * cfg.damping_alpha;
  const double sqrt_m = std::sqrt(total_mass_);
  const Vec3 om0 = s.qdot.segment<3>(3);
  const auto w0 = s.qdot.tail(nd);

  const Vec3 pi0 = floating_start(floating_, in, s, fc, nd, ws);

  VecX& x = ws.fl_x;
  VecX& dx = ws.fl_dx;
  x.resize(3 + nd);
  x.head<3>() = om0;
  x.tail(nd) = w0;
  info.converged = false;
  info.stiffness_evaluations = 0;
  for (int it = 0; it < cfg.max_newton_iterations; ++it) {
    floating_residual(in, s, pi0, x, true, ws);
    ++info.stiffness_evaluations;
    ws.fl_lu.compute(ws.fl_jac);
    dx = -ws.fl_lu.solve(ws.fl_r);
    info.newton_iterations = it + 1;
    if (!dx.allFinite()) {
      info.diverged = true;
      return info;
    }
    // As the linear step's test, in m/s: omega's change times the body's radius of gyration.
    const double step_norm = std::max(dx.head<3>().cwiseAbs().maxCoeff() * floating_.gyration,
                                      dx.tail(nd).cwiseAbs().maxCoeff() / sqrt_m);
    if (step_norm < cfg.newton_tolerance) {
      x += dx;
      info.converged = true;
      break;
    }
    // Backtracking on |r| (the residual is not a gradient: the gyroscopic terms).
    const double r0 = ws.fl_r.norm();
    double t = 1.0;
    for (int ls = 0; ls < 8; ++ls) {
      ws.fl_trial = x + t * dx;
      floating_residual(in, s, pi0, ws.fl_trial, false, ws);
      if (ws.fl_r.norm() <= (1.0 - 1e-4 * t) * r0) break;
      t *= 0.5;
    }
    x += t * dx;
  }

  // The new state, into a copy: a diverged step leaves the state as it was.
  const Vec3 om = x.head<3>();
  const auto w = x.tail(nd);
  const Vec3 u = (s.qdot.head<3>() + (h * sqrt_m) * cfg.gravity) / damp;
  VecX& q = ws.fl_q;
  q.resize(s.q.size());
  q.head<3>() = s.q.head<3>() + h * u;
  q.segment<3>(3) = compose_rotations(s.q.segment<3>(3), h * om);
  q.tail(nd) = s.q.tail(nd) + h * w;
  // RMS node speed from the kinetic energy: sum m |v|^2 = |sqrt(m) u|^2 + 2 T_rel.
  ws.fl_body.evaluate(floating_, q.tail(nd));
  const double two_t = u.squaredNorm() + om.dot(ws.fl_body.inertia * om) +
                       2.0 * om.dot(ws.fl_body.s * w) + w.squaredNorm();
  if (!q.allFinite() || !x.allFinite() || !std::isfinite(two_t) ||
      std::sqrt(std::max(two_t, 0.0)) / sqrt_m > cfg.max_speed) {
    info.diverged = true;
    return info;
  }
  s.q.swap(q);
  s.qdot.head<3>() = u;
  s.qdot.segment<3>(3) = om;
  s.qdot.tail(nd) = w;
  return info;
}

VecX ReducedModel::velocities(const VecX& q, const VecX& qdot) const {
  if (config.frame == Frame::Linear) return basis_ * qdot;
  const Eigen::Index nd = deformation_dim();
  const Mat3 rot = rotation_matrix(q.segment<3>(3));
  const Vec3 u = qdot.head<3>() / std::sqrt(total_mass_);
  const Vec3 om = qdot.segment<3>(3);
  const auto deform = basis_.rightCols(nd);
  const VecX r = rest_about_com_ + deform * q.tail(nd);
  const VecX uw = deform * qdot.tail(nd);
  VecX v(r.size());
  for (int i = 0; i < num_nodes_; ++i)
    v.segment<3>(3 * i) = u + rot * (om.cross(r.segment<3>(3 * i)) + uw.segment<3>(3 * i));
  return v;
}

}  // namespace softrom
