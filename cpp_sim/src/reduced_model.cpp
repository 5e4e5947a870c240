#include "reduced_model.h"

#include "nnls.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <stdexcept>
#include <exception>
#include <mutex>
#include <thread>

namespace softrom {

ReducedModel::ReducedModel(const TetMesh& mesh, const StableNeoHookean& material,
                           const VecX& mass, const MatX& basis,
                           const std::vector<int>& cubature_elements,
                           const std::vector<double>& cubature_weights,
                           const std::vector<int>& surface_nodes,
                           const std::vector<std::array<int, 3>>& surface_faces)
    : num_nodes_(mesh.num_nodes),
      basis_cols_(basis.cols()),
      material_(material),
      surface_nodes_(surface_nodes),
      basis_(basis),
      rest_(mesh.rest) {
  const int md = elastic_dim();
  total_mass_ = mass.sum();
  rest_com_.setZero();
  for (int i = 0; i < num_nodes_; ++i) rest_com_ += mass[i] * mesh.rest.segment<3>(3 * i);
  rest_com_ /= total_mass_;

  const Eigen::Index nk = static_cast<Eigen::Index>(cubature_elements.size());
  grad_.resize(9 * nk, md);
  wvol_.reserve(nk);
  for (Eigen::Index k = 0; k < nk; ++k) {
    const int e = cubature_elements[k];
    const Tet& t = mesh.tets[e];
    Eigen::Matrix<double, 12, Eigen::Dynamic> u(12, md);
    for (int a = 0; a < 4; ++a) u.middleRows<3>(3 * a) = basis.block(3 * t[a], kTranslations, 3, md);
    grad_.middleRows(9 * k, 9) = dfdx(mesh.dm_inv[e]) * u;
    wvol_.push_back(cubature_weights[k] * mesh.volume[e]);
  }

  const int ns = static_cast<int>(surface_nodes.size());
  surface_rows_.resize(3 * ns, basis.cols());
  surface_rest_.resize(3 * ns);
  node_mass_surface_.resize(ns);
  std::vector<int> local(num_nodes_, -1);
  for (int c = 0; c < ns; ++c) {
    const int i = surface_nodes[c];
    local[i] = c;
    surface_rows_.middleRows(3 * c, 3) = basis.middleRows(3 * i, 3);
    surface_rest_.segment<3>(3 * c) = mesh.rest.segment<3>(3 * i);
    node_mass_surface_[c] = mass[i];
  }
  faces_.reserve(surface_faces.size());
  for (const auto& f : surface_faces) {
    std::array<int, 3> lf{local[f[0]], local[f[1]], local[f[2]]};
    if (lf[0] < 0 || lf[1] < 0 || lf[2] < 0)
      throw std::invalid_argument("surface_faces uses a node that is not in surface_nodes");
    faces_.push_back(lf);
  }
  control_basis_ = MatX::Zero(deformation_dim(), 0);
  k_rest_ = elastic_stiffness(VecX::Zero(md), false);
}

void ReducedModel::set_control_basis(const MatX& bc) { control_basis_ = bc; }

ReducedState ReducedModel::rest_state() const {
  ReducedState s;
  s.q = VecX::Zero(basis_cols_);
  s.qdot = VecX::Zero(basis_cols_);
  s.impulses = VecX::Zero(3 * surface_nodes_.size());
  return s;
}

void ReducedModel::elastic(const VecX& qd, bool project, double* energy, VecX* force,
                           MatX* stiff) const {
  const Eigen::Index md = qd.size();
  const Eigen::Index nk = static_cast<Eigen::Index>(wvol_.size());
  // vec(F_e) = vec(I) + G_e q_e for every cubature element at once.
  VecX fall = grad_ * qd;
  VecX pall(force ? 9 * nk : 0);
  RowMatX hg(stiff ? 9 * nk : 0, md);
  double en = 0.0;
  for (Eigen::Index k = 0; k < nk; ++k) {
    double* fv = fall.data() + 9 * k;
    fv[0] += 1.0;
    fv[4] += 1.0;
    fv[8] += 1.0;
    const Eigen::Map<const Mat3> f(fv);
    const double w = wvol_[k];
    if (energy) en += w * material_.energy_density(f);
    if (force) {
      const Mat3 p = material_.pk1(f);
      Eigen::Map<Vec9>(pall.data() + 9 * k) = w * Eigen::Map<const Vec9>(p.data());
    }
    if (stiff) {
      Mat9 dp = material_.dpdf(f);
      if (project && !nearly_psd<9>(dp)) dp = project_psd<9>(dp);
      hg.middleRows(9 * k, 9).noalias() = (w * dp) * grad_.middleRows(9 * k, 9);
    }
  }
  if (energy) *energy = en;
  if (force) force->noalias() = -(grad_.transpose() * pall);
  if (stiff) {
    stiff->noalias() = grad_.transpose() * hg;
    // Symmetrise away round-off so the LDL^T sees an exactly symmetric matrix.
    *stiff = 0.5 * (*stiff + stiff->transpose()).eval();
  }
}

double ReducedModel::elastic_energy(const VecX& qd) const {
  double e;
  elastic(qd, false, &e, nullptr, nullptr);
  return e;
}

VecX ReducedModel::elastic_forces(const VecX& qd) const {
  VecX f;
  elastic(qd, false, nullptr, &f, nullptr);
  return f;
}

MatX ReducedModel::elastic_stiffness(const VecX& qd, bool project) const {
  MatX k;
  elastic(qd, project, nullptr, nullptr, &k);
  return k;
}

VecX ReducedModel::positions(const VecX& q) const { return rest_ + basis_ * q; }

Vec3 ReducedModel::com_velocity(const VecX& qdot) const {
  return qdot.head<3>() / std::sqrt(total_mass_);
}

Vec3 ReducedModel::com(const VecX& q) const {
  return rest_com_ + q.head<3>() / std::sqrt(total_mass_);
}

// Quadratic pressure drag on surface triangles advancing into still fluid (Pan & Manocha's
// heuristic): f = -1/2 rho C_d A max(n.v, 0)^2 n, shared equally by the three nodes.
// Returns the reduced force at (q, qdot) and its velocity Jacobian.
void ReducedModel::drag(const VecX& q, const VecX& qdot, VecX& f, MatX& jac) const {
  const Eigen::Index m = basis_cols_;
  f.setZero(m);
  jac.setZero(m, m);
  const VecX xs = surface_rest_ + surface_rows_ * q;
  const VecX vs = surface_rows_ * qdot;
  const double c = 0.5 * config.fluid_density * config.drag_coefficient;
  VecX w(m);
  for (const auto& tri : faces_) {
    const Vec3 a = xs.segment<3>(3 * tri[0]), b = xs.segment<3>(3 * tri[1]),
               d = xs.segment<3>(3 * tri[2]);
    Vec3 n = (b - a).cross(d - a);
    const double twice_area = n.norm();
    if (twice_area <= 0.0) continue;
    n /= twice_area;
    const Vec3 v = (vs.segment<3>(3 * tri[0]) + vs.segment<3>(3 * tri[1]) +
                    vs.segment<3>(3 * tri[2])) /
                   3.0;
    const double vn = n.dot(v);
    if (vn <= 0.0) continue;
    const double ca = c * 0.5 * twice_area;
    // w = U_t^T n with U_t the mean of the three nodes' rows of B_r (accumulated in place:
    // no heap temporaries in this per-face loop, which runs on every rollout thread).
    const Vec3 n3 = n / 3.0;
    w.noalias() = surface_rows_.middleRows(3 * tri[0], 3).transpose() * n3;
    w.noalias() += surface_rows_.middleRows(3 * tri[1], 3).transpose() * n3;
    w.noalias() += surface_rows_.middleRows(3 * tri[2], 3).transpose() * n3;
    f -= ca * vn * vn * w;
    jac.selfadjointView<Eigen::Lower>().rankUpdate(w, -2.0 * ca * vn);
  }
  jac.triangularView<Eigen::StrictlyUpper>() = jac.transpose();
}

// Penalty ground: a stiff spring on penetration with critical-ish damping and regularised
// Coulomb friction, evaluated at the Newton iterate (implicit in position).
void ReducedModel::penalty_contacts(const VecX& q, const VecX& v, VecX& f, MatX& jac) const {
  const Eigen::Index m = basis_cols_;
  f.setZero(m);
  jac.setZero(m, m);  // d f / d v (position terms are scaled by dt by the caller)
  const double h = config.dt;
  const VecX xs = surface_rest_ + surface_rows_ * q;
  const VecX vs = surface_rows_ * v;
  for (size_t c = 0; c < surface_nodes_.size(); ++c) {
    const double z = xs[3 * c + 2] - config.ground_height;
    if (z >= 0.0) continue;
    const double mass = node_mass_surface_[c];
    const double k = config.penalty_stiffness > 0 ? config.penalty_stiffness
                                                  : mass * 0.25 / (h * h);
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
    const double scale = config.friction * fn / std::sqrt(vt.squaredNorm() + eps * eps);
    f -= scale * (rows.topRows(2).transpose() * vt);
    jac.noalias() -= scale * rows.topRows(2).transpose() * rows.topRows(2);
  }
}

// Staggered projection (Kaufman, Sueda, James & Pai 2008) in reduced coordinates.
//
// With A the Newton matrix of the step and v* the contact-free velocity, the post-contact
// velocity minimises 1/2 |v - v*|_A^2 under the per-node conditions of the paper's
// Eq. (LCPConstraint). Staggering alternates two convex problems until the velocities of the
// contact nodes stop changing:
//
//   normal:   min 1/2 |v - v'|_A^2          s.t. J_n,i v >= -z_i / dt      (friction held)
//   friction: min 1/2 |v - v''|_A^2 + sum_i mu lambda_n,i |J_t,i v|        (normals held)
//
// Both are solved in the primal, over the M + 6 reduced velocities, not over the 3k contact
// impulses: k contact rows of rank <= M + 6 make the impulses non-unique (Delassus matrices
// with condition numbers ~1e6), so Gauss-Seidel on impulses crawls, while the primal problems
// are strongly convex and small. The normal problem is solved exactly as a least-distance
// programme, the friction problem (maximal dissipation) by a reweighted least-squares step on
// |J_t,i v|_eps = sqrt(|J_t,i v|^2 + eps^2).
int ReducedModel::solve_contacts(const VecX& q, const MatX& a, VecX& v, VecX& impulses,
                                 StepInfo& info) const {
  const double h = config.dt;
  const double mu = config.friction;
  const double tol = config.contact_tolerance;
  const int ns = static_cast<int>(surface_nodes_.size());
  const Eigen::Index m = basis_cols_;
  // Candidate rows: every surface node on or near the ground, or heading there this step.
  std::vector<int> active;
  std::vector<double> gap;
  for (int c = 0; c < ns; ++c) {
    const double z = surface_rest_[3 * c + 2] + surface_rows_.row(3 * c + 2).dot(q) -
                     config.ground_height;
    const double vn = surface_rows_.row(3 * c + 2).dot(v);
    if (z + 2.0 * h * std::min(vn, 0.0) < config.contact_margin) {
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
    b[i] = -gap[i] / h;  // v_n >= -z / dt: on or above the plane at the end of the step
    lam_n[i] = std::max(old[3 * c + 2], 0.0);  // warm start by node id
    lam_t.segment<2>(2 * i) = old.segment<2>(3 * c);
  }
  const VecX v_free = v;
  Eigen::LLT<MatX> a_llt(a);
  const double eps = tol;  // smoothing of |v_t|: sticking nodes creep at most ~eps

  VecX vc_prev(3 * k), vc(3 * k);
  auto contact_velocities = [&](VecX& out) {
    out.head(k) = jn * v;
    out.tail(2 * k) = jt * v;
  };
  contact_velocities(vc_prev);
  MatX hess(m, m);
  int stagger = 0;
  for (; stagger < config.max_stagger_iterations; ++stagger) {
    // --- Normal problem with the friction impulses held fixed: with A = L L^T and
    // x = L^T (v - v'), it is the least-distance programme min |x| s.t. J_n L^{-T} x >= b -
    // J_n v', solved exactly by NNLS (Lawson & Hanson), whose active set copes with the
    // redundant rows; the multipliers are the normal impulses.
    const VecX v_prime = v_free + a_llt.solve(jt.transpose() * lam_t);
    {
      ++info.normal_iterations;
      const MatX et = a_llt.matrixL().solve(jn.transpose());  // (L^{-1} J_n^T), m x k
      VecX x, lam = lam_n;  // warm start: last stagger's (or step's) loaded nodes
      if (least_distance(et.transpose(), b - jn * v_prime, x, lam)) {
        v = v_prime + a_llt.matrixU().solve(x);
        lam_n = lam;
      } else {
        v = v_prime;  // unreachable for a ground plane (moving up is always feasible)
        lam_n.setZero();
      }
    }
    // --- Friction problem with the normal impulses held fixed.
    const VecX v_second = v_free + a_llt.solve(jn.transpose() * lam_n);
    // One reweighted least-squares step on the smoothed, strictly convex
    //   phi(v) = 1/2 |v - v''|_A^2 + sum_i c_i sqrt(|J_t,i v|^2 + eps^2),  c_i = mu lambda_n,i:
    // v minimises phi's quadratic majoriser at the current velocities, so phi decreases and
    // the friction impulses -c_i J_t,i v / |J_t,i v|_eps stay inside the Coulomb discs. One
    // step per stagger is enough: the stagger loop iterates to the joint fixed point, and
    // measured on the quadruped, more inner steps did not reduce the stagger count.
    VecX weight(k);
    ++info.friction_iterations;
    hess = a;
    for (int i = 0; i < k; ++i) {
      const double s = std::sqrt((jt.middleRows(2 * i, 2) * v).squaredNorm() + eps * eps);
      weight[i] = mu * lam_n[i] / s;
      if (weight[i] > 0.0)
        hess.noalias() += weight[i] * jt.middleRows(2 * i, 2).transpose() * jt.middleRows(2 * i, 2);
    }
    v = hess.llt().solve(a * v_second);
    for (int i = 0; i < k; ++i) lam_t.segment<2>(2 * i) = -weight[i] * (jt.middleRows(2 * i, 2) * v);
    contact_velocities(vc);
    // Converged when the velocities of the loaded nodes (and of every node's normal, so no
    // unloaded node is about to penetrate) stop changing.
    double change = (vc.head(k) - vc_prev.head(k)).cwiseAbs().maxCoeff();
    for (int i = 0; i < k; ++i)
      if (lam_n[i] > 0.0)
        change = std::max(change, (vc.segment<2>(k + 2 * i) - vc_prev.segment<2>(k + 2 * i))
                                      .cwiseAbs()
                                      .maxCoeff());
    vc_prev = vc;
    if (change < tol) {
      ++stagger;
      break;
    }
  }
  for (int i = 0; i < k; ++i) {
    impulses[3 * active[i]] = lam_t[2 * i];
    impulses[3 * active[i] + 1] = lam_t[2 * i + 1];
    impulses[3 * active[i] + 2] = lam_n[i];
  }
  return stagger;
}

StepInfo ReducedModel::step(ReducedState& s, const double* fc) const {
  StepInfo info;
  const double h = config.dt;
  const Eigen::Index m = basis_cols_;
  const int md = elastic_dim();
  const int nd = deformation_dim();
  const double sqrt_m = std::sqrt(total_mass_);

  // B_r^T M g: uniform gravity only loads the translation columns, as the rotation (about
  // the centre of mass) and deformation columns are mass-orthogonal to them. Actuation acts on
  // the deformation coordinates, never on the rigid ones.
  VecX f_ext = VecX::Zero(m);
  f_ext.head<3>() = sqrt_m * config.gravity;
  if (fc != nullptr && control_basis_.cols() > 0)
    f_ext.tail(nd).noalias() += control_basis_ * Eigen::Map<const VecX>(fc, control_basis_.cols());

  const bool swim = config.fluid_density > 0.0;
  VecX f_drag;
  MatX j_drag;
  if (swim) drag(s.q, s.qdot, f_drag, j_drag);

  // Reduced Rayleigh damping D = alpha I + beta K_r(rest): modal damping ratio beta w_i / 2
  // on the deformation coordinates; translations are damped only by alpha.

  VecX v = s.qdot;
  VecX f_el(md), r(m), dv(m), f_pen;
  MatX k_el(md, md), a(m, m), j_pen;
  Eigen::LDLT<MatX> ldlt(m);
  for (int it = 0; it < config.max_newton_iterations; ++it) {
    const VecX qn = s.q + h * v;
    // The exact reduced Hessian: I dominates A = I + dt^2 K_r + ..., so A stays positive
    // definite unless an element is crushed; only then is K_r projected (below), an M x M
    // eigen decomposition instead of one 9 x 9 decomposition per element.
    elastic(qn.tail(md), false, nullptr, &f_el, &k_el);
    r = v - s.qdot;
    r -= h * f_ext;
    r.tail(md) -= h * f_el;
    a.setIdentity();
    a.bottomRightCorner(md, md) += (h * h) * k_el;
    if (config.damping_alpha > 0.0) {
      r += h * config.damping_alpha * v;
      a.diagonal().array() += h * config.damping_alpha;
    }
    if (config.damping_beta > 0.0) {
      r.tail(md) += (h * config.damping_beta) * (k_rest_ * v.tail(md));
      a.bottomRightCorner(md, md) += (h * config.damping_beta) * k_rest_;
    }
    if (swim) {
      r -= h * (f_drag + j_drag * (v - s.qdot));
      a -= h * j_drag;
    }
    if (config.contact == ContactModel::Penalty) {
      penalty_contacts(qn, v, f_pen, j_pen);
      r -= h * f_pen;
      a -= h * j_pen;
    }
    ldlt.compute(a);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive() ||
        (ldlt.vectorD().array() <= 0.0).any()) {
      Eigen::SelfAdjointEigenSolver<MatX> es(k_el);
      const MatX k_psd = es.eigenvectors() * es.eigenvalues().cwiseMax(0.0).asDiagonal() *
                         es.eigenvectors().transpose();
      a.bottomRightCorner(md, md) += (h * h) * (k_psd - k_el);
      ldlt.compute(a);
    }
    dv = -ldlt.solve(r);
    info.newton_iterations = it + 1;
    if (!dv.allFinite()) {
      info.diverged = true;
      return info;
    }
    const double step_norm = dv.cwiseAbs().maxCoeff() / sqrt_m;
    v += dv;
    if (step_norm < config.newton_tolerance) break;
  }

  // Impulses are solved into a copy: a step that diverges leaves the whole state as it was.
  VecX impulses = s.impulses;
  if (config.contact == ContactModel::Staggered)
    info.stagger_iterations = solve_contacts(s.q, a, v, impulses, info);

  const VecX q_next = s.q + h * v;
  // Divergence: non-finite state or RMS node speed beyond any physical meaning.
  if (!v.allFinite() || !q_next.allFinite() || !impulses.allFinite() ||
      v.norm() / sqrt_m > config.max_speed) {
    info.diverged = true;
    return info;  // the state keeps its last good value
  }
  for (int c = 0; c < impulses.size() / 3; ++c)
    if (impulses[3 * c + 2] > 0.0) ++info.contacts;
  s.q = q_next;
  s.qdot = v;
  s.impulses.swap(impulses);
  return info;
}

void ReducedModel::rollout(const std::vector<ReducedState>& starts, const double* controls,
                           int batch, int horizon, int threads, double* rewards, double* final_q,
                           double* final_qdot, double* final_impulses, unsigned char* diverged,
                           double* com_traj, const MatX* observe, double* observed) const {
  const int c = control_dim();
  const Eigen::Index m = basis_cols_;
  const Vec3 d = config.direction;
  auto run = [&](int b) {
    ReducedState s = starts[starts.size() == 1 ? 0 : b];
    bool bad = false;
    for (int t = 0; t < horizon; ++t) {
      double reward = 0.0;
      if (!bad) {
        const StepInfo info = step(s, controls + (static_cast<size_t>(b) * horizon + t) * c);
        bad = info.diverged;
        if (!bad) reward = d.dot(com_velocity(s.qdot)) * config.dt;
      }
      rewards[static_cast<size_t>(b) * horizon + t] = reward;
      if (com_traj) {
        const Vec3 p = com(s.q);
        std::copy(p.data(), p.data() + 3, com_traj + (static_cast<size_t>(b) * horizon + t) * 3);
      }
      if (observe && observed) {
        // Linear observables of q_r per step (e.g. the linearised orientation).
        const Eigen::Index no = observe->rows();
        Eigen::Map<VecX>(observed + (static_cast<size_t>(b) * horizon + t) * no, no) =
            (*observe) * s.q;
      }
    }
    std::copy(s.q.data(), s.q.data() + m, final_q + static_cast<size_t>(b) * m);
    std::copy(s.qdot.data(), s.qdot.data() + m, final_qdot + static_cast<size_t>(b) * m);
    const Eigen::Index ni = s.impulses.size();
    std::copy(s.impulses.data(), s.impulses.data() + ni, final_impulses + static_cast<size_t>(b) * ni);
    diverged[b] = bad ? 1 : 0;
  };
  threads = std::max(1, std::min(threads, batch));
  if (threads == 1) {
    for (int b = 0; b < batch; ++b) run(b);
    return;
  }
  // Each rollout is independent and computed start to finish by one worker, so results do
  // not depend on the thread count or the schedule.
  // A worker that throws (bad_alloc) or a thread that cannot be started must not terminate
  // the interpreter: the first error is carried out of the pool and rethrown after joining.
  std::atomic<int> next{0};
  std::exception_ptr error;
  std::mutex error_mutex;
  auto worker = [&] {
    try {
      for (int b = next.fetch_add(1); b < batch; b = next.fetch_add(1)) run(b);
    } catch (...) {
      std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
      next.store(batch);  // the others stop at their next rollout
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(threads);
  try {
    for (int w = 0; w < threads; ++w) pool.emplace_back(worker);
  } catch (...) {
    // Fewer threads than asked: the started ones finish the batch between them.
    if (pool.empty()) worker();
  }
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
}

}  // namespace softrom
