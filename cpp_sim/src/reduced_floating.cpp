// The floating frame's implicit step (docs/FLOATING_FRAME.md; kinematics in floating_frame.h).
//
// State q = (sqrt(m) (c - c_0), theta, z), qdot = (sqrt(m) u, omega, w), R = exp([theta]x).
// Momentum-form implicit Euler, with c' = c + h u', R' = R exp(h omega'), z' = z + h w':
//
//   (1 + h alpha) u'  = u + h (g + F_d)                                            (translation)
//   (1 + h alpha) Pi' = exp(-h omega') (Pi + h tau_d)                              (rotation)
//   (1 + h alpha) p'  = p + h (dT/dz' + f_e(z') - beta K_0 w' + Q_a(z') + Q_d)     (deformation)
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
// Pi and p alike); beta K_0 on the deformation only. Uniform gravity loads c alone. Drag
// (F_d on c, tau_d about it in the body frame, Q_d on z) is the linear model's law on the
// surface where it is at the step's start, linearised in the new velocities (u', omega', w')
// as the linear model's is: its generalised force is B(q)^T F with B(q) the velocity rows
// [I / sqrt(m), -R [r_i]x, R U_i] of the surface nodes at q (floating_drag). The penalty
// ground's force (floating_penalty) enters the same way, on the same rows, evaluated at the
// iterate with each node's height after the step predicted by them; the staggered ground
// projects the contact-free velocities with them (floating_contacts).
//
// The solve (step_floating) is Newton on (u', omega', w') with a backtracking line search on
// |r|. solver = reference evaluates K(z') at every iterate; solver = fast keeps every other
// term of the Jacobian exact (O(M^2) each) and freezes K at K_0, evaluating K(z') only on a
// stall and, with the staggered ground, at the second iterate and once more at the end for
// the contact metric: on the cross swimmer (400 random-stroke steps) that was no stiffness
// evaluation at all (docs/FLOATING_FRAME.md, step 9).
#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>

#include "dense_kernels.h"
#include "reduced_model.h"
#include "staggered_projection.h"

namespace softrom {

void ReducedModel::deformation_rows_times(const VecX& a, VecX& out) const {
  // (The column-major copy of the rows, through the dispatched kernel: Eigen's row-major
  // product runs on the build's baseline SSE2.)
  const Eigen::Index rows = surface_cols_.rows();
  out.resize(rows);
  kernels::cols_times(surface_cols_.data() + kRigid * rows, rows, deformation_dim(),
                      a.data() + kRigid, out.data());
}

void ReducedModel::floating_surface(const VecX& q, Workspace& ws) const {
  const Eigen::Index ns = num_surface_nodes();
  const Mat3 rot = rotation_matrix(q.segment<3>(3));
  const Vec3 c = com(q);
  VecX& r = ws.fl_rs;
  deformation_rows_times(q, r);
  VecX& xs = ws.fl_xs;
  xs.resize(3 * ns);
  for (Eigen::Index i = 0; i < ns; ++i) {
    r.segment<3>(3 * i) += surface_rest_.segment<3>(3 * i) - rest_com_;
    xs.segment<3>(3 * i) = c + rot * r.segment<3>(3 * i);
  }
}

void ReducedModel::floating_node_velocities(const VecX& q, const VecX& qdot, VecX& out,
                                            Workspace& ws) const {
  // v_i = u + R (omega x r_i + U_i w), r_i from floating_surface at q.
  const Eigen::Index ns = num_surface_nodes();
  const Mat3 rot = rotation_matrix(q.segment<3>(3));
  const Vec3 u = qdot.head<3>() / std::sqrt(total_mass_);
  const Vec3 om = qdot.segment<3>(3);
  deformation_rows_times(qdot, ws.fl_uw);
  out.resize(3 * ns);
  for (Eigen::Index i = 0; i < ns; ++i)
    out.segment<3>(3 * i) =
        u + rot * (om.cross(ws.fl_rs.segment<3>(3 * i)) + ws.fl_uw.segment<3>(3 * i));
}

void ReducedModel::floating_velocity_row(const Mat3& rot, Eigen::Index c, Workspace& ws) const {
  RowMatX& rows = ws.fl_rows;
  rows.block<3, 3>(3 * c, 0) = (1.0 / std::sqrt(total_mass_)) * Mat3::Identity();
  rows.block<3, 3>(3 * c, 3) = -rot * cross_matrix(ws.fl_rs.segment<3>(3 * c));
  rows.block(3 * c, kRigid, 3, deformation_dim()).noalias() =
      rot * surface_rows_.block(3 * c, kRigid, 3, deformation_dim());
}

void ReducedModel::floating_velocity_rows(const ReducedState& s, const std::vector<int>& nodes,
                                          Workspace& ws) const {
  const Eigen::Index ns = num_surface_nodes(), m = basis_cols_;
  RowMatX& rows = ws.fl_rows;
  if (rows.rows() != 3 * ns || rows.cols() != m) rows.resize(3 * ns, m);
  const Mat3 rot = rotation_matrix(s.q.segment<3>(3));
  for (const int c : nodes) floating_velocity_row(rot, c, ws);
}

void ReducedModel::floating_penalty_start(const ReducedState& s, Workspace& ws) const {
  const Eigen::Index ns = num_surface_nodes(), nd = deformation_dim(), m = basis_cols_;
  // e_z^T B_i = [e_z^T / sqrt(m), (r_i x b)^T, (U_i^T b)^T] with b = R^T e_z, R's third row.
  ws.fl_pen_rot = rotation_matrix(s.q.segment<3>(3));
  const Vec3 b = ws.fl_pen_rot.row(2).transpose();
  MatX& n = ws.fl_pen_normal_cols;
  n.resize(ns, m);
  n.leftCols<2>().setZero();
  n.col(2).setConstant(1.0 / std::sqrt(total_mass_));
  for (Eigen::Index c = 0; c < ns; ++c)
    n.block<1, 3>(c, 3) = ws.fl_rs.segment<3>(3 * c).cross(b).transpose();
  const Eigen::Index rows = surface_cols_.rows();
  for (Eigen::Index j = kRigid; j < kRigid + nd; ++j) {
    const double* u = surface_cols_.data() + j * rows;
    double* out = n.data() + j * ns;
    for (Eigen::Index c = 0; c < ns; ++c)
      out[c] = b[0] * u[3 * c] + b[1] * u[3 * c + 1] + b[2] * u[3 * c + 2];
  }
  ws.fl_pen_rows_formed.assign(static_cast<size_t>(ns), 0);
  RowMatX& full = ws.fl_rows;
  if (full.rows() != 3 * ns || full.cols() != m) full.resize(3 * ns, m);
}

// The penalty ground in the floating frame: penalty_contacts' springs, dampers and regularised
// friction (penalty_normal_force, penalty_node_load) on the surface's velocity rows B_i at the
// step's start, with node i's height after the step predicted by them, z_i + h (B_i x)_z: the
// staggered ground's and the drag's linearisation. Its Jacobian is exact in x: -W^T W plus the
// friction's coupling to the normal force, sum_i a_i r_z,i^T (penalty_node_load), which the
// linear frame's step takes too (not symmetric: here LU takes it).
void ReducedModel::floating_penalty(const ReducedConfig& cfg, const VecX& x, bool jacobian,
                                    Workspace& ws) const {
  const Eigen::Index m = basis_cols_, mp = face_rows_pad_.cols();  // (negative_gram's width)
  const Eigen::Index ns = num_surface_nodes();
  const double h = cfg.dt;
  VecX& f = ws.fl_pen;
  f.setZero(m);
  ScratchRowMat& w = ws.pen_w;
  ScratchRowMat& coupling = ws.fl_pen_coupling;
  if (jacobian) {  // (they only grow: allocated once per worker and model)
    w.resize(3 * ns, mp);
    coupling.resize(ns, mp);
  }
  // Every node's normal velocity by the dispatched column kernel; a loaded node's full rows
  // only when it is first loaded this step (most of the surface never is).
  VecX& vn = ws.fl_pen_vn;
  vn.resize(ns);
  kernels::cols_times(ws.fl_pen_normal_cols.data(), ns, m, x.data(), vn.data());
  Eigen::Index loaded = 0;
  for (Eigen::Index c = 0; c < ns; ++c) {
    const double z = ws.fl_xs[3 * c + 2] + h * vn[c] - cfg.ground_height;
    if (z >= 0.0) continue;
    double jn = 0.0;
    const double fn = penalty_normal_force(cfg, static_cast<size_t>(c), z, vn[c], jn);
    if (fn <= 0.0) continue;
    if (!ws.fl_pen_rows_formed[static_cast<size_t>(c)]) {
      floating_velocity_row(ws.fl_pen_rot, c, ws);
      ws.fl_pen_rows_formed[static_cast<size_t>(c)] = 1;
    }
    const double* rx = ws.fl_rows.data() + 3 * c * m;
    penalty_node_load(cfg.friction, fn, jn, rx, rx + m, rx + 2 * m, x.data(), m, mp, f.data(),
                      jacobian ? w.data() + 3 * loaded * mp : nullptr,
                      jacobian ? coupling.data() + loaded * mp : nullptr);
    ++loaded;
  }
  if (!jacobian) return;
  negative_gram(w.data(), 3 * loaded, ws.pen_gram, ws.fl_pen_jac);
  add_penalty_coupling(coupling.data(), w.data(), loaded, m, mp, ws.fl_pen_jac);
}

void ReducedModel::floating_drag(const ReducedConfig& cfg, const ReducedState& s,
                                 Workspace& ws) const {
  if (cfg.solver == Solver::Fast) {
    floating_drag_fast(cfg, s, ws);
    return;
  }
  // The surface's velocity rows at q are B_i = [I / sqrt(m), -R [r_i]x, R U_i], so a face's
  // column (the mean of its nodes' B_i^T n) is [n / sqrt(m); r_f x n_b; U_f^T n_b], with
  // n_b = R^T n, r_f the face's body centroid and U_f the mean of its nodes' rows of U (the
  // linear model's face rows): no rows are formed.
  const Eigen::Index nd = deformation_dim();
  floating_node_velocities(s.q, s.qdot, ws.fl_vs, ws);
  struct Context {
    const ReducedModel& model;
    Mat3 rot;
    double inv_sqrt_m;
    const VecX& r;
    Eigen::Index nd;
  };
  const Context ctx{*this, rotation_matrix(s.q.segment<3>(3)), 1.0 / std::sqrt(total_mass_),
                    ws.fl_rs, nd};
  // (One reference captured: std::function keeps it without allocating.)
  const FaceColumn column = [&ctx](Eigen::Index t, const Vec3& n, Eigen::Ref<VecX> out) {
    const auto& f = ctx.model.faces_[t];
    const Vec3 n_b = ctx.rot.transpose() * n;
    const VecX& r = ctx.r;
    const Vec3 centroid =
        (r.segment<3>(3 * f[0]) + r.segment<3>(3 * f[1]) + r.segment<3>(3 * f[2])) / 3.0;
    out.head<3>() = ctx.inv_sqrt_m * n;
    out.segment<3>(3) = centroid.cross(n_b);
    out.tail(ctx.nd).noalias() =
        ctx.model.face_rows_.block(3 * t, kRigid, 3, ctx.nd).transpose() * n_b;
  };
  drag_on_surface(cfg, ws.fl_xs, ws.fl_vs, column, ws.f_drag, &ws.j_drag, ws.drag_w,
                  ws.drag_cols, &ws.drag_coef, &ws.fl_speed);
}

void ReducedModel::floating_stiffness(const ReducedConfig& cfg, const ReducedState& s,
                                      const VecX& x, Workspace& ws) const {
  const Eigen::Index nd = deformation_dim();
  // (The cubature's kernels on q_e = (0, 0, 0, z'), as floating_residual's force.)
  ws.fl_qe.setZero(nd + 3);
  ws.fl_qe.tail(nd) = s.q.tail(nd) + cfg.dt * x.tail(nd);
  if (cfg.solver == Solver::Fast)
    elastic_stiffness_fast(ws.fl_qe, ws.fl_k, ws);
  else
    elastic_reference(ws.fl_qe, false, nullptr, nullptr, &ws.fl_k);
}

void ReducedModel::floating_drag_fast(const ReducedConfig& cfg, const ReducedState& s,
                                      Workspace& ws) const {
  // floating_drag's law and columns, the way drag_fast forms the linear model's: in the
  // body frame (a face's normal speed and its columns' deformation rows U_f^T n_b do not
  // depend on R), scalar corner arithmetic, and W's columns from the faces' padded rows by
  // combine_row_triples, whose first six rows (the linear basis's rigid columns) are then
  // replaced by the floating frame's [R n_b / sqrt(m); r_f x n_b].
  const Eigen::Index m = basis_cols_, mp = face_rows_pad_.cols();
  const Eigen::Index ns = num_surface_nodes();
  const Mat3 rot = rotation_matrix(s.q.segment<3>(3));
  const Vec3 om = s.qdot.segment<3>(3);
  const Vec3 u_body = rot.transpose() * (s.qdot.head<3>() / std::sqrt(total_mass_));
  // Body-frame node velocities R^T u + omega x r_i + U_i w (r_i: floating_surface's).
  VecX& vb = ws.fl_vs;
  vb.resize(3 * ns);
  deformation_rows_times(s.qdot, ws.fl_uw);
  for (Eigen::Index i = 0; i < ns; ++i)
    vb.segment<3>(3 * i) =
        u_body + om.cross(ws.fl_rs.segment<3>(3 * i)) + ws.fl_uw.segment<3>(3 * i);
  const double c_third = 0.5 * cfg.fluid_density * cfg.drag_coefficient / 3.0;
  const double* x = ws.fl_rs.data();
  const Eigen::Index n_adv = advancing_faces(x, vb.data(), c_third, ws);
  MatX& w = ws.drag_w;
  const VecX& coef = ws.drag_coef;
  const double inv_sqrt_m = 1.0 / std::sqrt(total_mass_);
  for (Eigen::Index i = 0; i < n_adv; ++i) {
    const Vec3 n_b = Eigen::Map<const Vec3>(ws.drag_normals.data() + 3 * i);
    const std::ptrdiff_t* corner = face_corners_.data() + 3 * ws.drag_faces[i];
    const Vec3 centroid = (Eigen::Map<const Vec3>(x + corner[0]) +
                           Eigen::Map<const Vec3>(x + corner[1]) +
                           Eigen::Map<const Vec3>(x + corner[2])) /
                          3.0;
    w.col(i).head<3>() = inv_sqrt_m * (rot * n_b);
    w.col(i).segment<3>(3) = centroid.cross(n_b);
  }
  ws.drag_pad.resize(mp);
  kernels::cols_times(w.data(), mp, n_adv, coef.data(), ws.drag_pad.data());
  ws.f_drag = -ws.drag_pad.head(m);
  ws.drag_cols = n_adv;
  // J_d = -W W^T, every step (the Newton matrix holds it), by the Gram kernel: W's columns
  // are the kernel's rows. Eigen's rank update took 3x the time (it runs on the build's
  // baseline SSE2; the kernels dispatch to AVX2 + FMA at run time).
  negative_gram(w.data(), n_adv, ws.fl_gram, ws.j_drag);
}

void ReducedModel::floating_residual(const StepInputs& in, const ReducedState& s,
                                     const Vec3& pi0, const VecX& x, bool jacobian,
                                     const MatX* stiffness, Workspace& ws) const {
  const ReducedConfig& cfg = in.config;
  const FloatingCoefficients& co = floating_;
  const Eigen::Index nd = deformation_dim(), m = basis_cols_;
  const double h = cfg.dt, damp = 1.0 + h * cfg.damping_alpha;
  const double sqrt_m = std::sqrt(total_mass_);
  const bool swim = cfg.fluid_density > 0.0;
  const bool penalty = cfg.contact == ContactModel::Penalty;
  // Rotation rows are divided by sqrt(m) r_g, which makes them mass-scaled velocities like
  // the others: one norm serves the line search.
  const double row_scale = 1.0 / (sqrt_m * co.gyration);
  const Vec3 u = x.head<3>();
  const Vec3 om = x.segment<3>(3);
  const auto w = x.tail(nd);
  ws.fl_z = s.q.tail(nd) + h * w;
  FloatingBody& body = ws.fl_body;
  body.evaluate(co, ws.fl_z);
  // The drag, linearised in the new velocities about the step's start: F + J_d (x - qdot_n).
  VecX& load = ws.fl_load;
  if (swim) {
    ws.fl_dv = x - s.qdot;
    load = ws.f_drag;
    load.noalias() += ws.j_drag * ws.fl_dv;
  } else {
    load.setZero(m);
  }
  // The penalty ground's force at x enters as the drag's does: F on c, the torque about it in
  // the start's body frame (turned back with Pi), Q on z.
  if (penalty) {
    floating_penalty(cfg, x, jacobian, ws);
    load += ws.fl_pen;
  }

  // Elastic force (and stiffness) of the deformation: the cubature's kernels on q_e =
  // (0, 0, 0, z'), the rotation columns held at zero (the frame carries the rotation).
  ws.fl_qe.setZero(nd + 3);
  ws.fl_qe.tail(nd) = ws.fl_z;
  const bool evaluate_k = jacobian && stiffness == nullptr;
  if (cfg.solver == Solver::Fast) {
    elastic_energy_force(ws.fl_qe, ws.fl_fe, ws);
    if (evaluate_k) elastic_stiffness_fast(ws.fl_qe, ws.fl_k, ws);
  } else {
    elastic_reference(ws.fl_qe, false, nullptr, &ws.fl_fe, evaluate_k ? &ws.fl_k : nullptr);
  }
  // (A pointer: without the Jacobian `stiffness` may be null, and binding *stiffness to a
  // reference was undefined behaviour even though k_el is then never read; UBSan, session 54.)
  const MatX* k_el = evaluate_k ? &ws.fl_k : stiffness;

  for (int a = 0; a < 3; ++a) ws.fl_yw[a].noalias() = co.y[a] * w;  // (dS/dz_k w)_a
  const Vec3 pi = body.inertia * om + body.s * w;
  const Mat3 turn_back = rotation_matrix(-h * om);
  const Vec3 pi_start = pi0 + h * load.segment<3>(3);  // Pi + h tau_d (body frame, at the start)
  VecX& r = ws.fl_r;
  r.resize(m);
  r.head<3>() = damp * u - s.qdot.head<3>() - h * (sqrt_m * cfg.gravity + load.head<3>());
  r.segment<3>(3) = (damp * pi - turn_back * pi_start) * row_scale;

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
  // (Products into their destinations, never inside a larger expression: Eigen would
  // evaluate them into a heap temporary, and a rollout's steps allocate nothing.)
  auto r_w = r.tail(nd);
  r_w.noalias() = body.s.transpose() * om;
  r_w += w;
  r_w *= damp;
  r_w -= ws.fl_p0;
  r_w -= h * (g + ws.fl_fe.tail(nd) + load.tail(nd));
  if (cfg.damping_beta > 0.0)
    r_w.noalias() += (h * cfg.damping_beta) * (k_rest_.bottomRightCorner(nd, nd) * w);
  if (actuated) {
    torque_free = inertia_inv * (body.s * f);
    ws.fl_tmp.noalias() = body.s.transpose() * torque_free;
    r_w -= h * (f - ws.fl_tmp);
  }
  if (!jacobian) return;

  // The Jacobian d r / d(u', omega', w'); z' = z + h w' brings a factor h to every
  // z-derivative. E_k = d Pi / dz_k = dI/dz_k omega + dS/dz_k w, which is also
  // d(dT/dz_k)/d omega.
  MatX& e = ws.fl_e;
  e.resize(3, nd);
  for (Eigen::Index k = 0; k < nd; ++k)
    e.col(k) = body.d_inertia(k, om) + Vec3(ws.fl_yw[0][k], ws.fl_yw[1][k], ws.fl_yw[2][k]);
  MatX& jac = ws.fl_jac;
  jac.setZero(m, m);
  jac.topLeftCorner<3, 3>().diagonal().setConstant(damp);
  jac.block<3, 3>(3, 3) =
      (damp * body.inertia -
       h * turn_back * cross_matrix(pi_start) * right_jacobian(-h * om)) * row_scale;
  jac.block(3, kRigid, 3, nd) = (damp * (body.s + h * e)) * row_scale;
  jac.block(kRigid, 3, nd, 3) = damp * body.s.transpose() - h * e.transpose();
  // Y_omega = sum_a omega_a Y_a: d p / dz = Y_omega^T = -Y_omega, d(dT/dz)/dw = Y_omega;
  // d^2 T / dz_k dz_l = |omega|^2 tr(C_kl) - omega^T C_kl omega.
  auto jww = jac.bottomRightCorner(nd, nd);
  jww.diagonal().setConstant(damp);
  // (sum_ab omega_a omega_b C_ab by its diagonal terms and symmetric pairs: 9 updates of the
  // M x M block, not 15.)
  for (int a = 0; a < 3; ++a) {
    jww.noalias() -= (h * (damp + 1.0) * om[a]) * co.y[a];
    jww.noalias() += (h * h * (om[a] * om[a] - om2)) * co.c[4 * a];
    const int b = (a + 1) % 3, lo = std::min(a, b), hi = std::max(a, b);
    jww.noalias() += (h * h * om[lo] * om[hi]) * co.c_pair[lo + hi - 1];
  }
  jww.noalias() += (h * h) * k_el->bottomRightCorner(nd, nd);
  if (cfg.damping_beta > 0.0) jww += (h * cfg.damping_beta) * k_rest_.bottomRightCorner(nd, nd);
  if (actuated) {
    // d Q_a / dz_k = -[dS_k^T a + S^T I^-1 (dS_k f - dI_k a)], (dS_k f)_a = (Y_a f)_k,
    // (dS_k^T a)_l = (sum_b a_b Y_b)_(k, l).
    const Vec3& a = torque_free;
    std::array<VecX, 3>& yf = ws.fl_yf;
    for (int b = 0; b < 3; ++b) yf[b].noalias() = co.y[b] * f;
    MatX& ya = ws.fl_ya;
    ya = a[0] * co.y[0] + a[1] * co.y[1] + a[2] * co.y[2];
    MatX& sti = ws.fl_sti;
    sti.noalias() = body.s.transpose() * inertia_inv;  // M x 3
    for (Eigen::Index k = 0; k < nd; ++k) {
      const Vec3 inner = Vec3(yf[0][k], yf[1][k], yf[2][k]) - body.d_inertia(k, a);
      // r_w has -h Q_a, so + h^2 (dS_k^T a + S^T I^-1 inner) in column k.
      jww.col(k) += (h * h) * ya.row(k).transpose();
      jww.col(k).noalias() += (h * h) * (sti * inner);
    }
  }
  if (swim || penalty) {  // the load's rows: -h J, the rotation's turned back by exp(-h omega')
    const MatX* j_load = swim ? &ws.j_drag : &ws.fl_pen_jac;  // J_d, J_pen or their sum
    if (swim && penalty) {
      ws.fl_load_jac = ws.j_drag + ws.fl_pen_jac;
      j_load = &ws.fl_load_jac;
    }
    jac.topRows<3>() -= h * j_load->topRows<3>();
    ws.fl_turned_drag.noalias() = turn_back * j_load->middleRows<3>(3);
    jac.middleRows<3>(3) -= (h * row_scale) * ws.fl_turned_drag;
    jac.bottomRows(nd) -= h * j_load->bottomRows(nd);
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
  ws.fl_p0.noalias() = ws.fl_body.s.transpose() * om0;
  ws.fl_p0 += w0;
  return ws.fl_body.inertia * om0 + ws.fl_body.s * w0;
}

void ReducedModel::floating_residual_for_tests(const StepInputs& in, const ReducedState& s,
                                               const VecX& fc, const VecX& x, MatX& residual,
                                               MatX& jacobian, Workspace& ws) const {
  const Vec3 pi0 = floating_start(floating_, in, s, fc.data(), deformation_dim(), ws);
  const bool penalty = in.config.contact == ContactModel::Penalty;
  if (in.config.fluid_density > 0.0 || penalty) floating_surface(s.q, ws);
  if (in.config.fluid_density > 0.0) floating_drag(in.config, s, ws);
  if (penalty) floating_penalty_start(s, ws);
  floating_residual(in, s, pi0, x, true, nullptr, ws);
  residual = ws.fl_r;
  jacobian = ws.fl_jac;
}

StepInfo ReducedModel::step_floating(const StepInputs& in, ReducedState& s, const double* fc,
                                     Workspace& ws) const {
  const ReducedConfig& cfg = in.config;
  StepInfo info;
  const Eigen::Index nd = deformation_dim();
  const double h = cfg.dt;
  const double sqrt_m = std::sqrt(total_mass_);
  const bool swim = cfg.fluid_density > 0.0;
  const bool staggered = cfg.contact == ContactModel::Staggered;
  const bool penalty = cfg.contact == ContactModel::Penalty;
  if (swim || staggered || penalty) floating_surface(s.q, ws);
  if (swim) {
    ScopedTimer drag_timer(cfg.profile ? &info.time_drag : nullptr);
    floating_drag(cfg, s, ws);
  }
  if (penalty) floating_penalty_start(s, ws);
  ScopedTimer timer(cfg.profile ? &info.time_dynamics : nullptr);
  const Vec3 pi0 = floating_start(floating_, in, s, fc, nd, ws);

  // solver = reference: Newton, the stiffness K(z') evaluated at every iterate. solver =
  // fast: the same Jacobian with K frozen at K_0 (every other term of it is O(M^2) and kept
  // exact), so an iteration evaluates forces only. K(z') at the iterate replaces it when the
  // iteration stalls: a step no smaller than half the last (the linear fast step's test), or
  // a rate that would leave more than four iterations to the tolerance. The rotation rows
  // hold no stiffness, so they are solved exactly whatever K: R Pi is kept to the square of
  // the final step, as by exact Newton.
  const bool exact = cfg.solver == Solver::Reference;
  const MatX* frozen = exact ? nullptr : &k_rest_;
  VecX& x = ws.fl_x;
  VecX& dx = ws.fl_dx;
  x = s.qdot;
  info.converged = false;
  info.stiffness_evaluations = 0;
  double prev_norm = std::numeric_limits<double>::infinity();
  // The fast solver's full step is tried with the (cheap, K-frozen) Jacobian: when it is
  // taken, as it nearly always is, the next iteration starts from that residual and Jacobian.
  bool evaluated_at_x = false;
  // An unconverged step returns the iterate of least residual, not the last: where the line
  // search fails (8 halvings without a decrease) the iteration still moves by t = 1/256, and
  // on very fast spin (h |omega| ~ 2.5 rad a step and more) 30 such moves had ended with |r|
  // three times the start's and the kinetic energy 4x, reported only as unconverged.
  double start_norm = 0.0, best_norm = std::numeric_limits<double>::infinity();
  for (int it = 0; it < cfg.max_newton_iterations; ++it) {
    if (!evaluated_at_x) floating_residual(in, s, pi0, x, true, frozen, ws);
    evaluated_at_x = false;
    const double r_norm = ws.fl_r.norm();
    if (it == 0) start_norm = r_norm;
    if (r_norm < best_norm) {
      best_norm = r_norm;
      ws.fl_best = x;
    }
    if (exact) ++info.stiffness_evaluations;
    ws.fl_lu.compute(ws.fl_jac);
    dx = ws.fl_lu.solve(ws.fl_r);
    dx = -dx;
    info.newton_iterations = it + 1;
    if (!dx.allFinite()) {
      info.diverged = true;
      return info;
    }
    // As the linear step's test, max |dv| / sqrt(m) in m/s, omega's change times the body's
    // radius of gyration.
    auto norm_of = [&](const VecX& d) {
      return std::max({d.head<3>().cwiseAbs().maxCoeff() / sqrt_m,
                       d.segment<3>(3).cwiseAbs().maxCoeff() * floating_.gyration,
                       d.tail(nd).cwiseAbs().maxCoeff() / sqrt_m});
    };
    double step_norm = norm_of(dx);
    if (step_norm < cfg.newton_tolerance) {
      x += dx;
      info.converged = true;
      break;
    }
    // Stalled: a rate above 1/2, or so slow a rate that more than four iterations would
    // remain before the tolerance (a heuristic threshold, not tuned: a stiffness evaluation
    // costs a few frozen iterations).
    const double rate = step_norm / prev_norm;
    const bool stalled =
        it >= 1 && (rate > 0.5 || std::pow(rate, 4.0) * step_norm > cfg.newton_tolerance);
    // With the staggered ground, K(z') at the second iterate, which gives the rest of the
    // iteration Newton's rate. A frozen K_0 stops at the tolerance with a linear-rate error
    // that, though below it, is biased the same way every step: on the cross walker's 8 gaits
    // it moved the mean speed 7 % from the tightly converged reference's (rms 0.0009 m/s over
    // the gaits, the reference's own 0.0002; 0.0004-0.0005 with this refresh;
    // benchmarks/accuracy_solvers.py --frame floating).
    const bool for_contact = staggered && it == 1 && frozen == &k_rest_;
    if (!exact && (stalled || for_contact)) {
      // The frozen K too far from K(z') for a useful rate (or the contact step's refresh,
      // above): the stiffness at this iterate, kept (at worst every iteration, which is exact
      // Newton).
      floating_stiffness(cfg, s, x, ws);
      ++info.stiffness_evaluations;
      frozen = &ws.fl_k;
      floating_residual(in, s, pi0, x, true, frozen, ws);
      ws.fl_lu.compute(ws.fl_jac);
      dx = ws.fl_lu.solve(ws.fl_r);
      dx = -dx;
      if (!dx.allFinite()) {
        info.diverged = true;
        return info;
      }
      step_norm = norm_of(dx);
    }
    prev_norm = step_norm;
    // Backtracking on |r| (the residual is not a gradient: the gyroscopic terms).
    const double r0 = ws.fl_r.norm();
    double t = 1.0;
    for (int ls = 0; ls < 8; ++ls) {
      ws.fl_trial = x + t * dx;
      const bool with_jacobian = !exact && ls == 0;
      floating_residual(in, s, pi0, ws.fl_trial, with_jacobian, frozen, ws);
      if (ws.fl_r.norm() <= (1.0 - 1e-4 * t) * r0) {
        evaluated_at_x = with_jacobian;
        break;
      }
      t *= 0.5;
    }
    if (evaluated_at_x)
      x.swap(ws.fl_trial);
    else
      x += t * dx;
  }
  if (!info.converged && info.newton_iterations > 0) {
    floating_residual(in, s, pi0, x, false, frozen, ws);
    if (!(ws.fl_r.norm() <= best_norm)) x = ws.fl_best;  // (a NaN residual too)
    // No iterate came nearer a solution than the start: the step was not solved at all, and
    // its answer would be the previous velocity carried on, not this step's dynamics.
    if (!(std::min(ws.fl_r.norm(), best_norm) < start_norm)) info.diverged = true;
  }

  timer.stop();
  // Ground contact projects the contact-free velocity; its impulses go into a copy.
  VecX& impulses = ws.impulses_next;
  if (staggered) {
    impulses = s.impulses;
    // (The metric's K: exact Newton's from its last Jacobian; the fast solver's evaluated at
    // x. Its refresh at the second iterate is too far from the end: on 48 tripod gaits the
    // per-gait speeds then spread 0.0109 m/s (rms) about the tight reference's, against the
    // reference's own 0.0076, and 0.0085 with K at the end.)
    info.stagger_iterations = floating_contacts(in, s, x, impulses, exact, ws, info);
  }

  // The new state, into a copy: a diverged step leaves the state as it was.
  const Vec3 u = x.head<3>();
  const Vec3 om = x.segment<3>(3);
  const auto w = x.tail(nd);
  VecX& q = ws.fl_q;
  q.resize(s.q.size());
  q.head<3>() = s.q.head<3>() + h * u;
  q.segment<3>(3) = compose_rotations(s.q.segment<3>(3), h * om);
  q.tail(nd) = s.q.tail(nd) + h * w;
  // RMS node speed from the kinetic energy: sum m |v|^2 = |sqrt(m) u|^2 + 2 T_rel.
  ws.fl_body.evaluate(floating_, q.tail(nd));
  const double two_t = u.squaredNorm() + om.dot(ws.fl_body.inertia * om) +
                       2.0 * om.dot(ws.fl_body.s * w) + w.squaredNorm();
  if (info.diverged || !q.allFinite() || !x.allFinite() || !std::isfinite(two_t) ||
      (staggered && !impulses.allFinite()) ||
      std::sqrt(std::max(two_t, 0.0)) / sqrt_m > cfg.max_speed) {
    info.diverged = true;
    return info;
  }
  s.q.swap(q);
  s.qdot.head<3>() = u;
  s.qdot.segment<3>(3) = om;
  s.qdot.tail(nd) = w;
  if (staggered) {
    for (Eigen::Index c = 0; c < impulses.size() / 3; ++c)
      if (impulses[3 * c + 2] > 0.0) ++info.contacts;
    s.impulses.swap(impulses);
  }
  return info;
}

int ReducedModel::floating_contacts(const StepInputs& in, const ReducedState& s, VecX& v,
                                    VecX& impulses, bool stiffness_at_v, Workspace& ws,
                                    StepInfo& info) const {
  const ReducedConfig& cfg = in.config;
  const Eigen::Index nd = deformation_dim(), m = basis_cols_;
  // Candidates as the linear model's: within the margin, or reaching the ground in two steps
  // at their normal velocity under v (the nodes at the step's start, floating_surface's).
  // The rows predict a node's height after the step at first order in h omega; the exact
  // rotation adds its drift, e_z^T R ((E - I - h [omega]x) r_c + (E - I) h U_c w) with
  // E = exp(h [omega]x), which the candidate test and the bounds take: without it, a beam
  // driven at 2 body weights (h |omega| up to 0.07) ended steps with nodes 2.3 mm into the
  // ground, 5.9 mm at 3 body weights (session 51). The bounds' drift is predicted at the
  // step's start velocity, nearer the step's end than v* is on the ground (on 400 steps of
  // each walker's 0.8 body-weight gait the re-solve below followed on 8-33 % of steps; with
  // the drift at v*, and session 51's re-solve test, on 20-98 %); the candidate test takes its
  // bound (set_velocity's), so only the candidates' drift is evaluated.
  const double h = cfg.dt, damp = 1.0 + h * cfg.damping_alpha;
  floating_node_velocities(s.q, v, ws.fl_vs, ws);
  const Mat3 rot = rotation_matrix(s.q.segment<3>(3));
  const Vec3 up = rot.row(2).transpose();  // R^T e_z: e_z^T R x = up . x
  const double inv_sqrt_m = 1.0 / std::sqrt(total_mass_);
  // Node c's normal velocity and drift at the velocity `at` (set_velocity's): U_c w is one
  // 3 x M product.
  const VecX* at = nullptr;
  Vec3 u_at, om_at;
  Mat3 turn;
  double rot_sq = 0.0, rot_w = 0.0;
  const auto set_velocity = [&](const VecX& x) {
    at = &x;
    u_at = x.head<3>() * inv_sqrt_m;
    om_at = x.segment<3>(3);
    turn = rotation_matrix(h * om_at);
    // |E - I - h [omega]x| <= e^t - 1 - t and |E - I| <= t (t = h |omega|): the drift's bound
    // (rot_sq |r_c| + rot_w |U_c|).
    const double t = h * om_at.norm();
    rot_sq = std::expm1(t) - t;
    rot_w = t * h * x.tail(nd).norm();
  };
  const auto node_at = [&](int c, double& drift) {
    const Vec3 uw = surface_rows_.block(3 * c, kRigid, 3, nd) * at->tail(nd);
    const Vec3 r = ws.fl_rs.segment<3>(3 * c);
    const Vec3 r_end = r + h * uw;
    drift = up.dot(turn * r_end - r_end - h * om_at.cross(r));
    return u_at.z() + up.dot(om_at.cross(r) + uw);
  };
  const auto drift_bound = [&](int c) {
    return rot_sq * ws.fl_rs.segment<3>(3 * c).norm() + rot_w * surface_deform_norms_[c];
  };
  set_velocity(s.qdot);
  const auto gap_of = [&](int c) { return ws.fl_xs[3 * c + 2] - cfg.ground_height; };
  const auto vn_of = [&](int c) { return ws.fl_vs[3 * c + 2] - drift_bound(c) / h; };
  if (pick_candidates(cfg, gap_of, vn_of, impulses, ws, info) == 0) return 0;
  const std::vector<int>& active = ws.contact_active;
  const std::vector<double>& gap = ws.contact_gap;
  ws.contact_drift.resize(active.size());
  for (size_t i = 0; i < active.size(); ++i) node_at(active[i], ws.contact_drift[i]);
  // The candidates' velocity rows (the solve reads only theirs, by surface node id).
  floating_velocity_rows(s, active, ws);
  const RowMatX& rows = ws.fl_rows;
  // The metric: the velocity response to an impulse over the step, the kinetic metric at z'
  // (u: 1, omega: I(z'), the coupling S(z'), w: 1) with the damping, plus h^2 K(z') + h beta
  // K_0 on z and -h J_d: the linear model's Newton matrix with its mass made exact. (The
  // momentum-form Jacobian is not symmetric, and the projection needs a metric.)
  // K is exact Newton's last (ws.fl_k: at z' to within the Newton tolerance); the fast
  // solver's is evaluated here, at the end, as the linear fast step does for its metric
  // (which measured the metric's stiffness at the step's end to matter).
  if (!stiffness_at_v) {
    floating_stiffness(cfg, s, v, ws);
    ++info.stiffness_evaluations;
  }
  ws.fl_z = s.q.tail(nd) + h * v.tail(nd);
  FloatingBody& body = ws.fl_body;
  body.evaluate(floating_, ws.fl_z);
  MatX& a = ws.a;
  auto build = [&](const auto& k_dd) {
    a.setZero(m, m);
    a.topLeftCorner<3, 3>().diagonal().setConstant(damp);
    a.block<3, 3>(3, 3) = damp * body.inertia;
    a.block(3, kRigid, 3, nd) = damp * body.s;
    a.block(kRigid, 3, nd, 3) = damp * body.s.transpose();
    auto add = a.bottomRightCorner(nd, nd);
    add.diagonal().array() += damp;
    add += (h * h) * k_dd + (h * cfg.damping_beta) * k_rest_.bottomRightCorner(nd, nd);
    if (cfg.fluid_density > 0.0) a -= h * ws.j_drag;
  };
  build(ws.fl_k.bottomRightCorner(nd, nd));
  Eigen::LLT<MatX>& a_llt = ws.a_llt;
  a_llt.compute(a);
  if (a_llt.info() != Eigen::Success) {  // a crushed element: K projected, as the linear step
    Eigen::SelfAdjointEigenSolver<MatX> es(ws.fl_k.bottomRightCorner(nd, nd));
    build(es.eigenvectors() * es.eigenvalues().cwiseMax(0.0).asDiagonal() *
          es.eigenvectors().transpose());
    a_llt.compute(a);
    if (a_llt.info() != Eigen::Success) {
      info.diverged = true;
      return 0;
    }
  }
  if (!ws.contact) ws.contact = std::make_unique<StaggeredProjection>();
  ws.contact_v_free = v;
  int staggers = ws.contact->solve(cfg, rows, active, gap, a, a_llt, v, impulses, ws.nnls, info,
                                   &ws.contact_drift);
  // The drift was predicted, and the candidates picked, before the step's end velocity v was
  // known. Re-solve from v*, warm-started, with the drift at v while the solve is not the
  // fixed point under it (a loaded node's drift moved by more than the contact tolerance
  // times dt, or an unloaded one's bound rose past its velocity), or while a node outside the
  // candidates ends below its bound (as the linear model's solve_contacts). A node's normal
  // velocity at v is at least its velocity at v* (ws.fl_vs) less |du| + |d omega| |r_c| +
  // |U_c| |dw| and its drift's bound; only nodes that bound cannot clear are evaluated.
  const VecX& v_free = ws.contact_v_free;
  double du = 0.0, dom = 0.0, dw = 0.0;
  const auto vn_at_least = [&](int c) {
    const double r = ws.fl_rs.segment<3>(3 * c).norm(), un = surface_deform_norms_[c];
    return ws.fl_vs[3 * c + 2] - du - dom * r - un * dw - drift_bound(c) / h;
  };
  const auto vn_end = [&](int c) {
    double drift;
    const double vn = node_at(c, drift);
    return vn + drift / h;
  };
  for (int round = 0;; ++round) {
    set_velocity(v);
    // The solve is still the fixed point under the new drift unless a loaded node's bound
    // moved (by more than the tolerance), or an unloaded one's rose by more than it and now
    // exceeds the node's velocity. (A bound that did not move is the solve's own: its slack
    // is staggering's, as in the linear frame, which a re-solve would not change.)
    const double tol = cfg.contact_tolerance;
    bool moved = false;
    for (size_t i = 0; i < active.size(); ++i) {
      const int c = active[i];
      double drift;
      const double vn = node_at(c, drift);
      const double change = drift - ws.contact_drift[i];
      ws.contact_drift[i] = drift;
      if (impulses[3 * c + 2] > 0.0) {
        moved = moved || std::abs(change) > tol * h;
      } else {
        const double bound = cfg.normal_velocity_bound(gap[i]) - drift / h;
        moved = moved || (change < -tol * h && vn < bound - tol);
      }
    }
    du = (v.head<3>() - v_free.head<3>()).norm() * inv_sqrt_m;
    dom = (v.segment<3>(3) - v_free.segment<3>(3)).norm();
    dw = (v.tail(nd) - v_free.tail(nd)).norm();
    const size_t before = active.size();
    const int added = add_missed_candidates(cfg, gap_of, vn_at_least, vn_end, ws, info);
    if (!moved && added == 0) break;
    if (round == kMaxCandidateRounds) {
      info.contact_converged = false;
      drop_unsolved_candidates(before, ws, info);
      break;
    }
    for (size_t i = before; i < active.size(); ++i) {
      ws.contact_drift.emplace_back();
      node_at(active[i], ws.contact_drift.back());
      floating_velocity_row(rot, active[i], ws);
    }
    v = ws.contact_v_free;
    info.contact_converged = true;  // the last solve's verdict (its v and impulses are kept)
    staggers += added > 0 ? ws.contact->solve(cfg, rows, active, gap, a, a_llt, v, impulses,
                                              ws.nnls, info, &ws.contact_drift)
                          : ws.contact->resolve(active, gap, &ws.contact_drift, v, impulses, info);
  }
  return staggers;
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
