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
#include <utility>

#include "material.h"

namespace softrom {

// [dP/dF]_+ = sum_i eigenvalue_i vec(Q_i) vec(Q_i)^T, with Q_i 3x3 matrices: the eigenvectors
// with their eigenvalues clamped at zero (directions whose clamped eigenvalue is zero are
// dropped), except that a positive-definite scaling block is given by its Cholesky factor.
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

// Rotation-variant SVD F = U diag(sigma) V^T: U and V rotations, sigma_0 >= sigma_1 >= |sigma_2|
// with sigma_2 < 0 when det F < 0. V diagonalises F^T F by cyclic Jacobi rotations run to
// convergence; U comes from an orthogonalisation of the columns of F V, in decreasing order of
// length, so it is orthonormal however degenerate F is. Several times faster than
// Eigen::JacobiSVD on 3x3 matrices, which matters as it runs once per element per iteration.
inline void rotation_variant_svd(const Mat3& f, Mat3& u, Eigen::Vector3d& sigma, Mat3& v) {
  Mat3 s = f.transpose() * f;
  v.setIdentity();
  const double scale = s.diagonal().sum();
  for (int sweep = 0; sweep < 20; ++sweep) {
    const double off = s(0, 1) * s(0, 1) + s(0, 2) * s(0, 2) + s(1, 2) * s(1, 2);
    if (!(off > 1e-30 * scale * scale)) break;  // also stops on NaN
    for (int p = 0; p < 2; ++p)
      for (int q = p + 1; q < 3; ++q) {
        // The Jacobi rotation that zeroes s(p, q) (Golub & Van Loan, section 8.5.2).
        const double spq = s(p, q);
        if (spq == 0.0) continue;
        const int r = 3 - p - q;
        const double theta = (s(q, q) - s(p, p)) / (2.0 * spq);
        const double t =
            std::abs(theta) > 1e150  // theta^2 would overflow; t -> 1 / (2 theta)
                ? 0.5 / theta
                : std::copysign(1.0, theta) / (std::abs(theta) + std::sqrt(theta * theta + 1.0));
        const double c = 1.0 / std::sqrt(t * t + 1.0), sn = t * c;
        s(p, p) -= t * spq;
        s(q, q) += t * spq;
        s(p, q) = s(q, p) = 0.0;
        const double srp = s(r, p), srq = s(r, q);
        s(r, p) = s(p, r) = c * srp - sn * srq;
        s(r, q) = s(q, r) = sn * srp + c * srq;
        const Eigen::Vector3d vp = v.col(p), vq = v.col(q);
        v.col(p) = c * vp - sn * vq;
        v.col(q) = sn * vp + c * vq;
      }
  }
  // Order the columns by decreasing eigenvalue of F^T F, and make V a rotation.
  int order[3] = {0, 1, 2};  // a three-element sort, written out (NaN-safe, branch-light)
  auto order_pair = [&](int i, int j) {
    if (s(order[j], order[j]) > s(order[i], order[i])) std::swap(order[i], order[j]);
  };
  order_pair(0, 1);
  order_pair(1, 2);
  order_pair(0, 1);
  Mat3 sorted;
  for (int k = 0; k < 3; ++k) sorted.col(k) = v.col(order[k]);
  v = sorted;
  if (v.determinant() < 0.0) v.col(2) = -v.col(2);

  const Mat3 b = f * v;  // columns sigma_k u_k
  const double tiny = 1e-300;
  auto any_orthogonal = [](const Eigen::Vector3d& a) {
    // A unit vector orthogonal to unit a: cross a with the axis it is least aligned with.
    Eigen::Vector3d axis = Eigen::Vector3d::Zero();
    Eigen::Index i;
    a.cwiseAbs().minCoeff(&i);
    axis[i] = 1.0;
    return a.cross(axis).normalized();
  };
  sigma[0] = b.col(0).norm();
  u.col(0) = sigma[0] > tiny ? Eigen::Vector3d(b.col(0) / sigma[0]) : Eigen::Vector3d::UnitX();
  Eigen::Vector3d r1 = b.col(1) - u.col(0).dot(b.col(1)) * u.col(0);
  sigma[1] = r1.norm();
  u.col(1) = sigma[1] > tiny * (1.0 + sigma[0]) ? Eigen::Vector3d(r1 / sigma[1])
                                                 : any_orthogonal(u.col(0));
  u.col(2) = u.col(0).cross(u.col(1));
  sigma[2] = u.col(2).dot(b.col(2));  // negative for an inverted F
}

inline ProjectedHessian project_stable_neo_hookean(const StableNeoHookean& m, const Mat3& f) {
  Mat3 u, v;
  Eigen::Vector3d sigma;
  rotation_variant_svd(f, u, sigma, v);
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
  // The scaling block is usually positive definite, and then it is its own projection: any
  // factor A = L L^T spans the same quadratic form as the eigenpairs, so a 3x3 Cholesky
  // replaces the eigensolver (the columns of L stand for sqrt(l) w, with unit "eigenvalues").
  const Eigen::LLT<Mat3> llt(a);
  if (llt.info() == Eigen::Success && llt.matrixLLT().diagonal().minCoeff() > 0.0) {
    const Mat3 l = llt.matrixL();
    for (int k = 0; k < 3; ++k) add(1.0, u * l.col(k).asDiagonal() * v.transpose());
    return out;
  }
  const Eigen::SelfAdjointEigenSolver<Mat3> es(a);
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d w = es.eigenvectors().col(k);
    add(es.eigenvalues()[k], u * w.asDiagonal() * v.transpose());
  }
  return out;
}

}  // namespace softrom
