// Ground contact: staggered projection (the default, Kaufman et al. 2008; the solve itself is
// StaggeredProjection's, staggered_projection.cpp) and a penalty model.
#include <algorithm>
#include <cmath>
#include <memory>

#include "dense_kernels.h"
#include "reduced_model.h"
#include "staggered_projection.h"

namespace softrom {

// Out of line, where StaggeredProjection is complete (the Workspace owns one by unique_ptr).
Workspace::Workspace() = default;
Workspace::~Workspace() = default;

// Picks the step's contact candidates and projects v onto their contact conditions
// (StaggeredProjection, in the worker's Workspace).
int ReducedModel::solve_contacts(const ReducedConfig& cfg, const VecX& q, const MatX& a,
                                 const Eigen::LLT<MatX>& a_llt, VecX& v, VecX& impulses,
                                 Workspace& ws, StepInfo& info) const {
  // Candidate rows: every surface node on or near the ground, or reaching it within two steps.
  if (!ws.ground_rows_ready) {  // near_ground has not formed them for this q and v
    ws.ground_z.noalias() = normal_rows_ * q;
    ws.ground_vn.noalias() = normal_rows_ * v;
  }
  ws.ground_rows_ready = false;
  const VecX& z_all = ws.ground_z;
  const VecX& vn_all = ws.ground_vn;
  const auto gap_of = [&](int c) { return ground_gap(cfg, c, z_all[c]); };
  const auto vn_of = [&](int c) { return vn_all[c]; };
  if (pick_candidates(cfg, gap_of, vn_of, impulses, ws, info) == 0) return 0;
  const std::vector<int>& active = ws.contact_active;
  const std::vector<double>& gap = ws.contact_gap;
  if (!ws.contact) ws.contact = std::make_unique<StaggeredProjection>();
  ws.contact_v_free = v;
  int staggers =
      ws.contact->solve(cfg, surface_rows_, active, gap, a, a_llt, v, impulses, ws.nnls, info);
  // The candidates are picked from the contact-free velocity, and the impulses on them can
  // drive another node down (a lever: the cross walker's arm pressed up at one end came down
  // 0.15 mm into the ground at the other, session 51). Such nodes join the candidates and the
  // solve is repeated from v_free, warm-started from the impulses it found.
  const auto vn_end = [&](int c) { return normal_rows_.row(c).dot(v); };
  double dv = 0.0;  // |v - v*|: |N_c| dv bounds node c's change of normal velocity
  const auto vn_at_least = [&](int c) { return vn_all[c] - normal_row_norms_[c] * dv; };
  for (int round = 0;; ++round) {
    dv = (v - ws.contact_v_free).norm();
    const size_t solved = active.size();
    if (add_missed_candidates(cfg, gap_of, vn_at_least, vn_end, ws, info) == 0) break;
    if (round == kMaxCandidateRounds) {  // still missing some: say so
      info.contact_converged = false;
      drop_unsolved_candidates(solved, ws, info);
      break;
    }
    v = ws.contact_v_free;
    info.contact_converged = true;  // the last solve's verdict (its v and impulses are kept)
    staggers +=
        ws.contact->solve(cfg, surface_rows_, active, gap, a, a_llt, v, impulses, ws.nnls, info);
  }
  return staggers;
}

// Penalty ground: a spring on penetration with a critical damper (ramped in over the first
// kPenaltyDamperRamp of sink) and regularised Coulomb friction, evaluated at the Newton
// iterate (implicit in position). The default stiffness is sized from the weight it must
// carry: the body's weight shared by the surface nodes that touch the ground at rest, per
// kPenaltySink (1 mm) of sink, plus 0.25 m_i / dt^2 (alone, that term let the quadruped's
// feet sink 6 cm), so a resting body sinks a little under 1 mm (0.89 mm for test_solver's
// block). It is an approximate model, and not a fast one: its springs are
// implicit in position, so it keeps Newton on the residual, each iteration with the penalty
// Jacobian (and, in the fast solver, the stiffness when Newton stalls); with the fast solver
// it runs at about 0.5-0.8 of staggered projection's rate (bench_rom.py's penalty/s, session
// 50).
double ReducedModel::penalty_normal_force(const ReducedConfig& cfg, size_t c, double z,
                                          double vz, double& jacobian_factor) const {
  const double h = cfg.dt;
  const double mass = node_mass_surface_[c];
  const double k = cfg.penalty_stiffness > 0
                       ? cfg.penalty_stiffness
                       : total_mass_ * std::abs(cfg.gravity.z()) / (rest_contacts_ * kPenaltySink) +
                             mass * 0.25 / (h * h);
  const double damp = 2.0 * std::sqrt(k * mass);
  const double sink = -z;
  if (sink < kPenaltyDamperRamp) {
    // The damper ramps in with the sink, f = sink (k - d v_z / delta_0) (Hunt-Crossley's
    // form), so the force is continuous where a node arrives. Its derivative in v_z, through
    // sink = -(z_0 + h v_z), is -(h (k - d v_z / delta_0) + d sink / delta_0), negative
    // wherever f > 0: the factor j_n is positive, so a node's normal row of W, sqrt(j_n) r_z,
    // stays real and the Jacobian exact.
    const double r = sink / kPenaltyDamperRamp;
    jacobian_factor = h * (k - damp * vz / kPenaltyDamperRamp) + damp * r;
    return std::max(0.0, k * sink - damp * vz * r);
  }
  jacobian_factor = k * h + damp;  // stiffness (through z = z0 + h v_z) and damping
  return std::max(0.0, k * sink - damp * vz);
}

// The penalty ground's smoothing of |v_t| (m/s): friction is regularised Coulomb,
// -mu f_n v_t / sqrt(|v_t|^2 + eps^2).
constexpr double kPenaltyFrictionEps = 1e-3;

// One loaded node's share of the penalty force, given its normal force f_n > 0, its Jacobian
// factor j_n = -d f_n / d v_z (k h + d beyond the damper's ramp) and its world velocity rows
// r_x, r_y, r_z (m entries each) in the generalised velocities v:
// f += f_n r_z - c (v_tx r_x + v_ty r_y), c = mu f_n / s,
// s = |v_t|_eps, and, when w is not null, the node's three rows of W (J_pen = -W^T W; mp
// columns, zero past m): sqrt(j_n) r_z, and the tangent rows times
// S = sqrt(c) (I - v_t v_t^T / (s (s + eps))). Both frames' fast penalty grounds sum it.
// -W^T W leaves out the friction's dependence on f_n, the rank-one (mu j_n / s) t r_z^T with
// t = v_tx r_x + v_ty r_y, which is not symmetric; when `coupling` is not null,
// a = (mu sqrt(j_n) / s) t goes there (mp columns, zero past m), so that the term is a times
// the node's normal row of W. The floating frame's Newton matrix takes it, factored by LU; the
// linear frame's, by one refinement of its symmetric part's solve (step_reference).
void penalty_node_load(double mu, double fn, double jn, const double* rx, const double* ry,
                       const double* rz, const double* v, Eigen::Index m, Eigen::Index mp,
                       double* f, double* w, double* coupling) {
  const double eps = kPenaltyFrictionEps;
  double vt0 = 0.0, vt1 = 0.0;
  for (Eigen::Index j = 0; j < m; ++j) {
    vt0 += rx[j] * v[j];
    vt1 += ry[j] * v[j];
  }
  const double s = std::sqrt(vt0 * vt0 + vt1 * vt1 + eps * eps);
  const double scale = mu * fn / s;
  const double ft0 = scale * vt0, ft1 = scale * vt1;
  for (Eigen::Index j = 0; j < m; ++j) f[j] += fn * rz[j] - (ft0 * rx[j] + ft1 * ry[j]);
  if (w == nullptr) return;
  const double sn = std::sqrt(jn), st = std::sqrt(scale);
  const double a = 1.0 / (s * (s + eps));
  const double s00 = st * (1.0 - a * vt0 * vt0), s01 = -st * a * vt0 * vt1,
               s11 = st * (1.0 - a * vt1 * vt1);
  double* wn = w;
  double* w0 = wn + mp;
  double* w1 = w0 + mp;
  for (Eigen::Index j = 0; j < m; ++j) {
    wn[j] = sn * rz[j];
    w0[j] = s00 * rx[j] + s01 * ry[j];
    w1[j] = s01 * rx[j] + s11 * ry[j];
  }
  for (Eigen::Index j = m; j < mp; ++j) wn[j] = w0[j] = w1[j] = 0.0;
  if (coupling == nullptr) return;
  const double cn = mu * sn / s;
  for (Eigen::Index j = 0; j < m; ++j) coupling[j] = cn * (vt0 * rx[j] + vt1 * ry[j]);
  for (Eigen::Index j = m; j < mp; ++j) coupling[j] = 0.0;
}

void add_penalty_coupling(const double* coupling, const double* w, Eigen::Index loaded,
                          Eigen::Index m, Eigen::Index mp, MatX& jac) {
  const Eigen::Map<const RowMatX> a(coupling, loaded, mp);
  const Eigen::Map<const RowMatX, 0, Eigen::OuterStride<>> n(w, loaded, mp,
                                                              Eigen::OuterStride<>(3 * mp));
  jac.noalias() += a.leftCols(m).transpose() * n.leftCols(m);  // (into jac: no temporary)
}

void ReducedModel::penalty_load_for_tests(const StepInputs& in, const VecX& q_n, const VecX& v,
                                          const VecX* x, VecX& force, MatX& symmetric,
                                          MatX& coupling, VecX& coupling_x,
                                          Workspace& ws) const {
  const VecX q = q_n + in.config.dt * v;
  penalty_contacts(in.config, q, v, force, &symmetric, ws);
  const bool fast = in.config.solver == Solver::Fast;
  if (fast) {
    penalty_coupling_matrix(ws, coupling);
  } else {
    coupling = ws.j_pen_coupling;
  }
  if (x == nullptr) return;
  if (fast) {
    penalty_coupling_times(*x, coupling_x, ws);
  } else {
    coupling_x = coupling * *x;
  }
}

void ReducedModel::penalty_contacts(const ReducedConfig& cfg, const VecX& q, const VecX& v,
                                    VecX& f, MatX* jac, Workspace& ws) const {
  if (cfg.solver == Solver::Fast) return penalty_contacts_fast(cfg, q, v, f, jac, ws);
  // The reference solver's arithmetic: Eigen's products, node by node. (Each is evaluated as
  // Eigen evaluates the expression it replaced, into the workspace's scratch instead of a
  // heap temporary: the same sums, bit for bit.)
  const Eigen::Index m = basis_cols_;
  f.setZero(m);
  if (jac) {  // d f / d v (the position terms through q = q_n + h v: times h)
    jac->setZero(m, m);
    ws.j_pen_coupling.setZero(m, m);
  }
  VecX& xs = ws.pen_xs;
  VecX& vs = ws.pen_vs;
  xs = surface_rest_;
  xs.noalias() += surface_rows_ * q;
  vs.noalias() = surface_rows_ * v;
  for (size_t c = 0; c < surface_nodes_.size(); ++c) {
    const double z = xs[3 * c + 2] - cfg.ground_height;
    if (z >= 0.0) continue;
    double jn = 0.0;
    const double fn = penalty_normal_force(cfg, c, z, vs[3 * c + 2], jn);
    if (fn <= 0.0) continue;
    const auto rows = surface_rows_.middleRows(3 * c, 3);
    f += fn * rows.row(2).transpose();
    if (jac) {
      ws.pen_row = jn * rows.row(2).transpose();
      jac->noalias() -= ws.pen_row * rows.row(2);
    }
    const Eigen::Vector2d vt(vs[3 * c], vs[3 * c + 1]);
    const double eps = kPenaltyFrictionEps;
    const double s = std::sqrt(vt.squaredNorm() + eps * eps);
    const double scale = cfg.friction * fn / s;
    ws.pen_ft.noalias() = scale * (rows.topRows(2).transpose() * vt);
    f -= ws.pen_ft;
    if (!jac) continue;
    // Exact Jacobian of -mu f_n v_t / |v_t|_eps in v_t: (mu f_n / s)(I - v_t v_t^T / s^2).
    const Eigen::Matrix2d dt_dv =
        scale * (Eigen::Matrix2d::Identity() - vt * vt.transpose() / (s * s));
    ws.pen_at.noalias() = rows.topRows(2).transpose() * dt_dv;
    jac->noalias() -= ws.pen_at * rows.topRows(2);
    // The friction's dependence on f_n (d f_n / d v = -j_n r_z^T): (mu j_n / s) t r_z^T.
    ws.pen_row.noalias() = (cfg.friction * jn / s) * (rows.topRows(2).transpose() * vt);
    ws.j_pen_coupling.noalias() += ws.pen_row * rows.row(2);
  }
}

// The fast solver's: the heights and normal velocities of every surface node by one pass of
// the column-major kernel over the normal rows, the tangent rows read only for loaded nodes,
// and the Jacobian's symmetric part as one Gram product. Its terms are negative semi-definite,
// so it is -W^T W with three rows of W per loaded node: sqrt(j_n) times its normal row, and
// S times its tangent rows, S = sqrt(c) (I - v_t v_t^T / (s (s + eps))) (c = mu f_n / s) the
// symmetric square root of the friction block c (I - v_t v_t^T / s^2) (in this form, free of
// the cancellation of 1 - eps / s at small |v_t|). Node by node with Eigen's products, the
// Jacobian took over half of a penalty step on the cross (a flat body: ~185 loaded nodes).
// The friction's coupling to the normal force stays in one row per loaded node
// (penalty_node_load's a), for penalty_coupling_times.
void ReducedModel::penalty_contacts_fast(const ReducedConfig& cfg, const VecX& q, const VecX& v,
                                         VecX& f, MatX* jac, Workspace& ws) const {
  const Eigen::Index m = basis_cols_, mp = face_rows_pad_.cols();  // (negative_gram's width)
  const Eigen::Index ns = normal_cols_.rows();
  f.setZero(m);
  VecX& zq = ws.pen_xs;
  VecX& vn = ws.pen_vs;
  zq.resize(ns);
  vn.resize(ns);
  kernels::cols_times_pair(normal_cols_.data(), ns, m, q.data(), v.data(), zq.data(), vn.data());
  ScratchRowMat& w = ws.pen_w;
  ScratchRowMat& coupling = ws.pen_coupling;
  if (jac) {  // (they only grow: allocated once per worker and model)
    w.resize(3 * ns, mp);
    coupling.resize(ns, mp);
  }
  Eigen::Index rows = 0;
  for (Eigen::Index c = 0; c < ns; ++c) {
    const double z = ground_gap(cfg, c, zq[c]);
    if (z >= 0.0) continue;
    double jn = 0.0;
    const double fn = penalty_normal_force(cfg, static_cast<size_t>(c), z, vn[c], jn);
    if (fn <= 0.0) continue;
    const double* rx = surface_rows_.data() + 3 * c * m;
    penalty_node_load(cfg.friction, fn, jn, rx, rx + m, rx + 2 * m, v.data(), m, mp, f.data(),
                      jac ? w.data() + rows * mp : nullptr,
                      jac ? coupling.data() + (rows / 3) * mp : nullptr);
    if (jac) rows += 3;
  }
  if (!jac) return;
  negative_gram(w.data(), rows, ws.pen_gram, *jac);
  ws.pen_loaded = rows / 3;  // the coupling stays in its rows: penalty_coupling_times
}

// C x = A^T (N x) (add_penalty_coupling's C), from the rows penalty_contacts_fast left, and
// C itself.
void ReducedModel::penalty_coupling_times(const VecX& x, VecX& out, Workspace& ws) const {
  const Eigen::Index m = basis_cols_, mp = face_rows_pad_.cols(), loaded = ws.pen_loaded;
  const Eigen::Map<const RowMatX> a(ws.pen_coupling.data(), loaded, mp);
  const Eigen::Map<const RowMatX, 0, Eigen::OuterStride<>> n(ws.pen_w.data(), loaded, mp,
                                                              Eigen::OuterStride<>(3 * mp));
  // (pen_nx only grows: the loaded count changes from iterate to iterate.)
  if (ws.pen_nx.size() < loaded) ws.pen_nx.resize(normal_cols_.rows());
  ws.pen_nx.head(loaded).noalias() = n.leftCols(m) * x;
  out.noalias() = a.leftCols(m).transpose() * ws.pen_nx.head(loaded);
}

void ReducedModel::penalty_coupling_matrix(Workspace& ws, MatX& out) const {
  const Eigen::Index m = basis_cols_;
  out.setZero(m, m);
  add_penalty_coupling(ws.pen_coupling.data(), ws.pen_w.data(), ws.pen_loaded, m,
                       face_rows_pad_.cols(), out);
}

}  // namespace softrom
