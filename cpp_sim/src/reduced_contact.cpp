// Ground contact: staggered projection (the default, Kaufman et al. 2008; the solve itself is
// StaggeredProjection's, staggered_projection.cpp) and a penalty model.
#include <algorithm>
#include <cmath>
#include <memory>

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
  return ws.contact->solve(cfg, surface_rows_, active, gap, a, a_llt, v, impulses, ws.nnls, info);
}

// Penalty ground: a spring on penetration with damping and regularised Coulomb friction,
// evaluated at the Newton iterate (implicit in position). The default stiffness is sized from
// the weight it must carry: the body's weight shared by the surface nodes that touch the
// ground at rest, per kPenaltySink (1 mm) of sink, plus 0.25 m_i / dt^2 (alone, that term let
// the quadruped's feet sink 6 cm), so a resting body sinks a little under 1 mm (0.89 mm for
// test_solver's block). It is an approximate model, and not a fast one: each Newton iteration
// needs the stiffness (its springs are implicit in position), so with the fast solver it runs
// at a fourth to a seventh of staggered projection's rate (bench_rom.py's penalty/s, 2026-12-07).
void ReducedModel::penalty_contacts(const ReducedConfig& cfg, const VecX& q, const VecX& v,
                                    VecX& f, MatX* jac, Workspace& ws) const {
  const Eigen::Index m = basis_cols_;
  f.setZero(m);
  if (jac) jac->setZero(m, m);  // d f / d v (the position terms through q = q_n + h v: times h)
  const double h = cfg.dt;
  // (Each product is evaluated as Eigen evaluates the expression it replaces, into the
  // workspace's scratch instead of a heap temporary: the same sums, bit for bit.)
  VecX& xs = ws.pen_xs;
  VecX& vs = ws.pen_vs;
  xs = surface_rest_;
  xs.noalias() += surface_rows_ * q;
  vs.noalias() = surface_rows_ * v;
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
    if (jac) {
      ws.pen_row = (k * h + damp) * rows.row(2).transpose();
      jac->noalias() -= ws.pen_row * rows.row(2);
    }
    const Eigen::Vector2d vt(vs[3 * c], vs[3 * c + 1]);
    const double eps = 1e-3;
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
  }
}

}  // namespace softrom
