// Quadratic fluid drag on the surface (the paper's swimming model).
#include <cmath>

#include "reduced_model.h"

namespace softrom {

// Quadratic pressure drag on surface triangles advancing into still fluid (Pan & Manocha's
// heuristic): f = -1/2 rho C_d A max(n.v, 0)^2 n, shared equally by the three nodes.
// Returns the reduced force at (q, qdot) and its velocity Jacobian (symmetric, negative
// semi-definite: a sum of -2 c A (n.v) w w^T with w = U_t^T n).
void ReducedModel::drag(const ReducedConfig& cfg, const VecX& q, const VecX& qdot, VecX& f,
                        MatX* jac, MatX& w, Eigen::Index& cols) const {
  const Eigen::Index m = basis_cols_;
  const Eigen::Index nf = static_cast<Eigen::Index>(faces_.size());
  const VecX xs = surface_rest_ + surface_rows_ * q;
  // A face's velocity is the mean of its nodes' (U_t qdot, U_t the mean of their rows): from
  // the node velocities, half the product of the face rows with qdot.
  const VecX vs = surface_rows_ * qdot;
  const double c = 0.5 * cfg.fluid_density * cfg.drag_coefficient;
  // Columns w_f = U_t^T n of the faces advancing into the fluid, scaled for one rank update.
  if (w.rows() != m || w.cols() < nf) w.resize(m, nf);
  VecX coef(nf), speed(nf);
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
    w.col(n_adv).noalias() = face_rows_.middleRows<3>(3 * t).transpose() * n;
    coef[n_adv] = ca * vn;
    speed[n_adv] = vn;
    ++n_adv;
  }
  // f = -sum ca vn^2 w,  df/dv = -sum 2 ca vn w w^T.
  f.noalias() = -(w.leftCols(n_adv) * coef.head(n_adv).cwiseProduct(speed.head(n_adv)));
  for (Eigen::Index t = 0; t < n_adv; ++t) w.col(t) *= std::sqrt(2.0 * coef[t]);
  cols = n_adv;
  if (jac != nullptr) drag_jacobian(w, cols, *jac);
}

void ReducedModel::drag_jacobian(const MatX& w, Eigen::Index cols, MatX& jac) const {
  const Eigen::Index m = basis_cols_;
  jac.setZero(m, m);
  jac.selfadjointView<Eigen::Lower>().rankUpdate(w.leftCols(cols), -1.0);
  jac.triangularView<Eigen::StrictlyUpper>() = jac.transpose();
}

}  // namespace softrom
