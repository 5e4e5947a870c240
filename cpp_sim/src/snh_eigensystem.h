// Closed-form eigensystem of the stable Neo-Hookean Hessian dP/dF (Smith, de Goes & Kim 2019,
// "Analytic Eigensystems for Isotropic Distortion Energies"), derived here for the energy in
// material.h. With the rotation-variant SVD F = U diag(sigma) V^T (U, V rotations, sigma_2
// negative when F is inverted) and s = lambda (J - 1) - mu, the nine eigenpairs are
//
//   twist  vec(U T_xy V^T), T_xy = (e_x e_y^T - e_y e_x^T) / sqrt(2):  mu + s sigma_z,
//   flip   vec(U L_xy V^T), L_xy = (e_x e_y^T + e_y e_x^T) / sqrt(2):  mu - s sigma_z,
//   scale  vec(U diag(w) V^T), (w, l) an eigenpair of the 3x3 matrix
//          A = mu I + lambda c c^T + s [[0, s2, s1], [s2, 0, s0], [s1, s0, 0]],
//          c = (s1 s2, s0 s2, s0 s1),
//
// for each pair (x, y) with z the third axis. Clamping the eigenvalues at zero is the same PSD
// projection that project_psd<9> computes numerically, at a fraction of the cost of a 9x9
// symmetric eigensolver, and the eigenvectors stay orthonormal however degenerate sigma is.
#pragma once

#include <Eigen/Dense>
#include <array>
#include <cmath>

#include "material.h"

namespace softrom {

// The eigenvectors as 3x3 matrices Q_i (vec(Q_i) is the eigenvector of dP/dF) with their
// eigenvalues clamped at zero. Directions whose clamped eigenvalue is zero are dropped.
struct ProjectedHessian {
  std::array<Mat3, 9> q;
  std::array<double, 9> eigenvalue;
  int count = 0;

  // dP/dF projected onto the PSD cone, as a 9x9 matrix on column-major vec(F).
  Mat9 matrix() const {
    Mat9 h = Mat9::Zero();
    for (int i = 0; i < count; ++i) {
      const Eigen::Map<const Vec9> v(q[i].data());
      h.noalias() += eigenvalue[i] * v * v.transpose();
    }
    return h;
  }
};

inline ProjectedHessian project_stable_neo_hookean(const StableNeoHookean& m, const Mat3& f) {
  const Eigen::JacobiSVD<Mat3> svd(f, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 u = svd.matrixU();
  Mat3 v = svd.matrixV();
  Eigen::Vector3d sigma = svd.singularValues();
  // Rotation-variant SVD: move any reflection into the smallest singular value.
  if (u.determinant() < 0.0) {
    u.col(2) = -u.col(2);
    sigma[2] = -sigma[2];
  }
  if (v.determinant() < 0.0) {
    v.col(2) = -v.col(2);
    sigma[2] = -sigma[2];
  }
  const double j = sigma[0] * sigma[1] * sigma[2];
  const double s = m.lambda * (j - 1.0) - m.mu;

  ProjectedHessian out;
  auto add = [&](double eigenvalue, const Mat3& q) {
    if (eigenvalue > 0.0) {
      out.q[out.count] = q;
      out.eigenvalue[out.count] = eigenvalue;
      ++out.count;
    }
  };
  static constexpr int kPairs[3][3] = {{0, 1, 2}, {0, 2, 1}, {1, 2, 0}};  // x, y, z
  const double inv_sqrt2 = 1.0 / std::sqrt(2.0);
  for (const auto& p : kPairs) {
    // U (e_x e_y^T) V^T = u_x v_y^T.
    const Mat3 xy = u.col(p[0]) * v.col(p[1]).transpose();
    const Mat3 yx = u.col(p[1]) * v.col(p[0]).transpose();
    add(m.mu + s * sigma[p[2]], inv_sqrt2 * (xy - yx));
    add(m.mu - s * sigma[p[2]], inv_sqrt2 * (xy + yx));
  }
  const Eigen::Vector3d c(sigma[1] * sigma[2], sigma[0] * sigma[2], sigma[0] * sigma[1]);
  Mat3 a = m.lambda * c * c.transpose();
  a.diagonal().array() += m.mu;
  a(0, 1) += s * sigma[2];
  a(0, 2) += s * sigma[1];
  a(1, 2) += s * sigma[0];
  a(1, 0) = a(0, 1);
  a(2, 0) = a(0, 2);
  a(2, 1) = a(1, 2);
  const Eigen::SelfAdjointEigenSolver<Mat3> es(a);
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d w = es.eigenvectors().col(k);
    add(es.eigenvalues()[k], u * w.asDiagonal() * v.transpose());
  }
  return out;
}

}  // namespace softrom
