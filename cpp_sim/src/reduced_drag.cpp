// Quadratic fluid drag on the surface (the paper's swimming model).
#include <cmath>

#include "dense_kernels.h"
#include "reduced_model.h"

namespace softrom {

// Quadratic pressure drag on surface triangles advancing into still fluid (Pan & Manocha's
// heuristic): f = -1/2 rho C_d A max(n.v, 0)^2 n, shared equally by the three nodes.
// Returns the reduced force at (q, qdot) and its velocity Jacobian (symmetric, negative
// semi-definite: a sum of -2 c A (n.v) w w^T with w = U_t^T n).
void ReducedModel::drag(const ReducedConfig& cfg, const VecX& q, const VecX& qdot, VecX& f,
                        MatX* jac, MatX& w, Eigen::Index& cols) const {
  const VecX xs = surface_rest_ + surface_rows_ * q;
  // A face's velocity is the mean of its nodes' (U_t qdot, U_t the mean of their rows): from
  // the node velocities, half the work of the face rows' product with qdot (a closed surface
  // has about twice as many faces as nodes).
  const VecX vs = surface_rows_ * qdot;
  const FaceColumn column = [this](Eigen::Index t, const Vec3& n, Eigen::Ref<VecX> out) {
    out.noalias() = face_rows_.middleRows<3>(3 * t).transpose() * n;
  };
  drag_on_surface(cfg, xs, vs, column, f, jac, w, cols);
}

void ReducedModel::drag_on_surface(const ReducedConfig& cfg, const VecX& xs, const VecX& vs,
                                   const FaceColumn& column, VecX& f, MatX* jac, MatX& w,
                                   Eigen::Index& cols, VecX* coef_scratch,
                                   VecX* speed_scratch) const {
  const Eigen::Index m = basis_cols_;
  const Eigen::Index nf = static_cast<Eigen::Index>(faces_.size());
  const double c = 0.5 * cfg.fluid_density * cfg.drag_coefficient;
  // Columns w_f = U_t^T n of the faces advancing into the fluid, scaled for one rank update.
  if (w.rows() != m || w.cols() < nf) w.resize(m, nf);
  VecX own_coef, own_speed;
  VecX& coef = coef_scratch ? *coef_scratch : own_coef;
  VecX& speed = speed_scratch ? *speed_scratch : own_speed;
  coef.resize(nf);
  speed.resize(nf);
  Eigen::Index n_adv = 0;
  for (Eigen::Index t = 0; t < nf; ++t) {
    const auto& tri = faces_[t];
    const Vec3 a = xs.segment<3>(3 * tri[0]), b = xs.segment<3>(3 * tri[1]),
               d = xs.segment<3>(3 * tri[2]);
    Vec3 n = (b - a).cross(d - a);
    const double twice_area = n.norm();
    if (twice_area <= 0.0) continue;
    n /= twice_area;
    const Vec3 vf = (vs.segment<3>(3 * tri[0]) + vs.segment<3>(3 * tri[1]) +
                     vs.segment<3>(3 * tri[2])) /
                    3.0;
    const double vn = n.dot(vf);
    if (vn <= 0.0) continue;
    const double ca = c * 0.5 * twice_area;
    column(t, n, w.col(n_adv));
    coef[n_adv] = ca * vn;
    speed[n_adv] = vn;
    ++n_adv;
  }
  // f = -sum ca vn^2 w,  df/dv = -sum 2 ca vn w w^T. (ca vn^2 into speed first: a product
  // with an expression operand would be evaluated into a heap temporary.)
  speed.head(n_adv) = coef.head(n_adv).cwiseProduct(speed.head(n_adv));
  f.noalias() = w.leftCols(n_adv) * speed.head(n_adv);
  f = -f;
  for (Eigen::Index t = 0; t < n_adv; ++t) w.col(t) *= std::sqrt(2.0 * coef[t]);
  cols = n_adv;
  if (jac != nullptr) drag_jacobian(w, cols, *jac);
}

// The fast solver's drag: the same law, force and factor W as drag(), through the dense
// kernels (the surface's positions and velocities by the column-major copy of its rows, the
// advancing faces' columns of W as combinations of their three rows), into the workspace.
// W's rows are padded with zeros to a multiple of 4 (ws.drag_w is mp x faces), so the
// potential's W^T g (kernels::cols_dot_times) runs over whole packets. Each column comes out
// already scaled for the factor (df/dv = -W W^T), and the force is formed from the scaled
// columns. (Measured in benchmarks/PROFILE.md, sessions 16 and 17.)
void ReducedModel::drag_fast(const ReducedConfig& cfg, const VecX& q, const VecX& qdot,
                             Workspace& ws) const {
  const Eigen::Index m = basis_cols_, mp = face_rows_pad_.cols();
  const Eigen::Index ns3 = surface_cols_.rows();
  VecX& xs = ws.drag_xs;
  VecX& vs = ws.drag_vs;
  xs.resize(ns3);
  vs.resize(ns3);
  kernels::cols_times_pair(surface_cols_.data(), ns3, m, q.data(), qdot.data(), xs.data(),
                           vs.data());
  xs += surface_rest_;
  const double c_third = 0.5 * cfg.fluid_density * cfg.drag_coefficient / 3.0;
  const Eigen::Index n_adv = advancing_faces(xs.data(), vs.data(), c_third, ws);
  const MatX& w = ws.drag_w;
  const VecX& coef = ws.drag_coef;
  ws.drag_pad.resize(mp);
  kernels::cols_times(w.data(), mp, n_adv, coef.data(), ws.drag_pad.data());
  ws.f_drag = -ws.drag_pad.head(m);
  ws.drag_cols = n_adv;
}

Eigen::Index ReducedModel::advancing_faces(const double* x, const double* v, double c_third,
                                           Workspace& ws) const {
  const Eigen::Index mp = face_rows_pad_.cols();
  const Eigen::Index nf = static_cast<Eigen::Index>(faces_.size());
  MatX& w = ws.drag_w;
  if (w.rows() != mp || w.cols() < nf) w.resize(mp, nf);
  // The face's force along -n, ca vn^2, is coef times its column's scale: the force is -W coef.
  VecX& coef = ws.drag_coef;
  coef.resize(nf);
  ws.drag_faces.resize(nf);
  ws.drag_normals.resize(3 * nf);
  Eigen::Index n_adv = 0;
  for (Eigen::Index t = 0; t < nf; ++t) {
    // Scalar arithmetic on the corners (Eigen's 3-vectors cost twice the instructions here; a
    // four-faces-per-vector kernel measured no faster, its corners loaded one by one), and the
    // normal scaled only for the faces that advance.
    const std::ptrdiff_t* corner = face_corners_.data() + 3 * t;
    const double* pa = x + corner[0];
    const double* pb = x + corner[1];
    const double* pd = x + corner[2];
    const double e0 = pb[0] - pa[0], e1 = pb[1] - pa[1], e2 = pb[2] - pa[2];
    const double g0 = pd[0] - pa[0], g1 = pd[1] - pa[1], g2 = pd[2] - pa[2];
    const double n0 = e1 * g2 - e2 * g1, n1 = e2 * g0 - e0 * g2, n2 = e0 * g1 - e1 * g0;
    const double* ua = v + corner[0];
    const double* ub = v + corner[1];
    const double* ud = v + corner[2];
    const double nv = n0 * (ua[0] + ub[0] + ud[0]) + n1 * (ua[1] + ub[1] + ud[1]) +
                      n2 * (ua[2] + ub[2] + ud[2]);
    if (nv <= 0.0) continue;  // receding, or degenerate (n = 0); NaN goes on, to be caught
    // With A = |n| / 2 the area, vn = nv / (3 |n|) the normal speed and ca = c A, the column's
    // scale sqrt(2 ca vn) (its outer products sum to -df/dv) is sqrt(c nv / 3): the area
    // cancels, and the unit normal times the scale is n sqrt(c nv / (3 |n|^2)), one square
    // root and one division a face. The force along -n, ca vn^2, is then (nv ns / 6) scale.
    const double ns = std::sqrt(c_third * nv / (n0 * n0 + n1 * n1 + n2 * n2));
    double* n = ws.drag_normals.data() + 3 * n_adv;
    n[0] = n0 * ns;
    n[1] = n1 * ns;
    n[2] = n2 * ns;
    coef[n_adv] = nv * ns * (1.0 / 6.0);
    ws.drag_faces[n_adv] = t;
    ++n_adv;
  }
  // W's scaled columns U_t^T n scale from each face's three rows (padded with zeros to mp).
  kernels::combine_row_triples(face_rows_pad_.data(), mp, ws.drag_faces.data(),
                               ws.drag_normals.data(), n_adv, w.data(), mp);
  return n_adv;
}

void ReducedModel::negative_gram(const double* rows, Eigen::Index count, MatX& gram,
                                 MatX& out) const {
  const Eigen::Index m = basis_cols_, mp = face_rows_pad_.cols();
  out.resize(m, m);
  if (count == 0) {
    out.setZero();
    return;
  }
  gram.resize(mp, mp);
  kernels::gram_lower(rows, rows, count, mp, gram.data());
  for (Eigen::Index j = 0; j < m; ++j)
    for (Eigen::Index i = j; i < m; ++i) out(i, j) = out(j, i) = -gram(i, j);
}

void ReducedModel::drag_jacobian(const MatX& w, Eigen::Index cols, MatX& jac) const {
  const Eigen::Index m = basis_cols_;
  jac.setZero(m, m);
  // No face advancing (a body at rest): nothing to add. Eigen's blocked rank update divides
  // by its inner size, so with zero columns it stopped the process (SIGFPE) once m was past
  // its small-matrix path (M + 6 = 48 here, not 26).
  if (cols == 0) return;
  // (w may have padding rows past m: drag_fast's.)
  jac.selfadjointView<Eigen::Lower>().rankUpdate(w.topLeftCorner(m, cols), -1.0);
  jac.triangularView<Eigen::StrictlyUpper>() = jac.transpose();
}

}  // namespace softrom
