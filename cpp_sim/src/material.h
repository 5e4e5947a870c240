// Stable Neo-Hookean hyperelasticity (Smith, de Goes & Kim 2018, in the form of Kim & Eberle,
// "Dynamic Deformables", 2022):
//
//   Psi(F) = mu/2 (I_C - 3) - mu (J - 1) + lambda/2 (J - 1)^2,   I_C = tr(F^T F), J = det F,
//
// with lambda = lambda_Lame + mu so that the small-strain limit is linear elasticity with
// Young's modulus E and Poisson ratio nu. Unlike StVK it resists compression and stays
// defined (and restoring) for inverted elements, which soft robots pressed into the ground
// do produce. Rest stability: P(I) = 0.
#pragma once

#include <Eigen/Dense>

namespace softrom {

using Mat3 = Eigen::Matrix3d;
using Mat9 = Eigen::Matrix<double, 9, 9>;
using Vec9 = Eigen::Matrix<double, 9, 1>;

struct StableNeoHookean {
  double mu = 0.0;
  double lambda = 0.0;

  static StableNeoHookean from_young_poisson(double E, double nu) {
    StableNeoHookean m;
    m.mu = E / (2.0 * (1.0 + nu));
    const double lame = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    m.lambda = lame + m.mu;
    return m;
  }

  // dJ/dF: the cofactor matrix, columns f1 x f2, f2 x f0, f0 x f1.
  static Mat3 cofactor(const Mat3& F) {
    Mat3 g;
    g.col(0) = F.col(1).cross(F.col(2));
    g.col(1) = F.col(2).cross(F.col(0));
    g.col(2) = F.col(0).cross(F.col(1));
    return g;
  }

  double energy_density(const Mat3& F) const {
    const double ic = F.squaredNorm();
    const double jm1 = F.determinant() - 1.0;
    return 0.5 * mu * (ic - 3.0) - mu * jm1 + 0.5 * lambda * jm1 * jm1;
  }

  // First Piola-Kirchhoff stress P = dPsi/dF.
  Mat3 pk1(const Mat3& F) const {
    const double jm1 = F.determinant() - 1.0;
    return mu * F + (lambda * jm1 - mu) * cofactor(F);
  }

  // dP/dF as a 9x9 matrix acting on column-major vec(F).
  Mat9 dpdf(const Mat3& F) const {
    const double jm1 = F.determinant() - 1.0;
    Mat3 g = cofactor(F);
    Vec9 gv = Eigen::Map<const Vec9>(g.data());
    Mat9 h = mu * Mat9::Identity() + lambda * gv * gv.transpose();
    // Hessian of J: block (i, j) is d(col i of cofactor)/d(col j of F).
    const double s = lambda * jm1 - mu;
    auto hat = [](const Eigen::Vector3d& v) {
      Mat3 m;
      m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
      return m;
    };
    const Mat3 f0 = hat(F.col(0)) * s, f1 = hat(F.col(1)) * s, f2 = hat(F.col(2)) * s;
    h.block<3, 3>(0, 3) -= f2;
    h.block<3, 3>(0, 6) += f1;
    h.block<3, 3>(3, 0) += f2;
    h.block<3, 3>(3, 6) -= f0;
    h.block<3, 3>(6, 0) -= f1;
    h.block<3, 3>(6, 3) += f0;
    return h;
  }
};

// True when a is positive semi-definite up to a relative tolerance: a Cholesky of a slightly
// shifted copy succeeds. Much cheaper than an eigen decomposition, and the stable Neo-Hookean
// Hessian is exactly singular at rest, so an unshifted Cholesky would fail there.
template <int N>
bool nearly_psd(const Eigen::Matrix<double, N, N>& a) {
  const double shift = 1e-9 * a.diagonal().cwiseAbs().maxCoeff();
  Eigen::Matrix<double, N, N> b = a;
  b.diagonal().array() += shift;
  return Eigen::LLT<Eigen::Matrix<double, N, N>>(b).info() == Eigen::Success;
}

// Projects a symmetric matrix onto the positive semi-definite cone (negative eigenvalues
// clamped to zero), so Newton's method on the implicit-Euler energy always descends.
template <int N>
Eigen::Matrix<double, N, N> project_psd(const Eigen::Matrix<double, N, N>& a) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> es(a);
  auto lam = es.eigenvalues();
  if (lam.minCoeff() >= 0.0) return a;
  lam = lam.cwiseMax(0.0);
  return es.eigenvectors() * lam.asDiagonal() * es.eigenvectors().transpose();
}

// d vec(F) / d x_e for a linear tet, x_e = (x0, x1, x2, x3) stacked (12). F = D_s D_m^{-1}.
inline Eigen::Matrix<double, 9, 12> dfdx(const Mat3& dm_inv) {
  Eigen::Matrix<double, 9, 12> d = Eigen::Matrix<double, 9, 12>::Zero();
  for (int j = 0; j < 3; ++j) {
    const double s = dm_inv(0, j) + dm_inv(1, j) + dm_inv(2, j);
    for (int i = 0; i < 3; ++i) {
      // F_ij = sum_k (x_{k+1,i} - x_{0,i}) Dminv_kj ; vec index i + 3 j
      d(i + 3 * j, i) = -s;
      for (int k = 0; k < 3; ++k) d(i + 3 * j, 3 * (k + 1) + i) = dm_inv(k, j);
    }
  }
  return d;
}

// The 12 rows of U (3N x cols, a basis or a block of one) that a tet's four nodes `tet` take,
// U_e, so that G_e = d vec(F_e) / dq = dfdx(D_m^-1) U_e for positions x = X + U q. The
// cubature's element gradients (ReducedModel) and its training data (reduced_element_forces)
// both gather them here. (Each call site keeps its own product dfdx * U_e, inside its own
// expression: returning the product from here changed reduced_element_forces' results in
// the last bit.)
template <class Nodes, class Basis>
Eigen::Matrix<double, 12, Eigen::Dynamic> element_rows(const Nodes& tet, const Basis& u) {
  Eigen::Matrix<double, 12, Eigen::Dynamic> rows(12, u.cols());
  for (int a = 0; a < 4; ++a) rows.template middleRows<3>(3 * a) = u.middleRows(3 * tet[a], 3);
  return rows;
}

}  // namespace softrom
