// The floating frame's coefficients and rotation helpers (floating_frame.h).
#include "floating_frame.h"

#include <Eigen/Geometry>
#include <algorithm>

namespace softrom {

FloatingCoefficients FloatingCoefficients::build(const VecX& rest, const VecX& mass,
                                                 double total_mass, const Eigen::MatrixXd& u) {
  const Eigen::Index n = mass.size(), m = u.cols();
  FloatingCoefficients co;
  // Rows a of every node: U_a (N x M), X_a (N), as mass-weighted copies for the sums.
  std::array<Eigen::MatrixXd, 3> ua, mua;
  std::array<VecX, 3> xa;
  for (int a = 0; a < 3; ++a) {
    ua[a].resize(n, m);
    xa[a].resize(n);
    for (Eigen::Index i = 0; i < n; ++i) {
      ua[a].row(i) = u.row(3 * i + a);
      xa[a][i] = rest[3 * i + a];
    }
    mua[a] = mass.asDiagonal() * ua[a];
  }
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      co.j0(a, b) = (mass.array() * xa[a].array() * xa[b].array()).sum();
      co.a[3 * a + b] = mua[b].transpose() * xa[a];
      co.c[3 * a + b] = mua[a].transpose() * ua[b];
    }
  co.c_pair = {co.c[1] + co.c[3], co.c[2] + co.c[6], co.c[5] + co.c[7]};
  // (U_k x U_l)_x = U_yk U_zl - U_zk U_yl, and cyclically; the same for X x U_l.
  for (int a = 0; a < 3; ++a) {
    const int p = (a + 1) % 3, q = (a + 2) % 3;
    co.y[a] = co.c[3 * p + q] - co.c[3 * q + p];
    co.s0[a] = co.a[3 * p + q] - co.a[3 * q + p];
  }
  const Mat3 i0 = co.j0.trace() * Mat3::Identity() - co.j0;
  const double largest = Eigen::SelfAdjointEigenSolver<Mat3>(i0).eigenvalues().maxCoeff();
  co.gyration = std::sqrt(std::max(largest, 0.0) / total_mass);
  return co;
}

void FloatingBody::evaluate(const FloatingCoefficients& co, const Eigen::Ref<const VecX>& z) {
  // C_ab z (M each): J's quadratic term is z . C_ab z, and dJ_ab/dz = A_ab + A_ba + C_ab z +
  // C_ba z (C_ab^T = C_ba).
  for (int p = 0; p < 9; ++p) cz[p].noalias() = co.c[p] * z;
  Mat3 j;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      const int ab = 3 * a + b, ba = 3 * b + a;
      j(a, b) = co.j0(a, b) + z.dot(co.a[ab] + co.a[ba]) + z.dot(cz[ab]);
      d[ab] = co.a[ab] + co.a[ba] + cz[ab] + cz[ba];
    }
  // (J is symmetric to round-off; symmetrised so that I(z) is exactly.)
  j = 0.5 * (j + j.transpose()).eval();
  inertia = j.trace() * Mat3::Identity() - j;
  s.resize(3, z.size());
  for (int a = 0; a < 3; ++a) {
    // (Into a contiguous vector first: a product into s's strided row is evaluated into a
    // heap temporary, and a rollout's steps allocate nothing.)
    sz.noalias() = co.y[a].transpose() * z;
    s.row(a) = (sz + co.s0[a]).transpose();
  }
}

Mat3 rotation_matrix(const Vec3& theta) {
  const double t = theta.norm();
  if (t == 0.0) return Mat3::Identity();
  return Eigen::AngleAxisd(t, theta / t).toRotationMatrix();
}

namespace {

Eigen::Quaterniond quaternion(const Vec3& theta) {
  const double t = theta.norm();
  if (t == 0.0) return Eigen::Quaterniond::Identity();
  return Eigen::Quaterniond(Eigen::AngleAxisd(t, theta / t));
}

}  // namespace

Vec3 compose_rotations(const Vec3& theta, const Vec3& phi) {
  Eigen::Quaterniond q = quaternion(theta) * quaternion(phi);
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();  // the same rotation, turned by at most pi
  const double s = q.vec().norm();
  if (s == 0.0) return Vec3::Zero();
  // angle = 2 atan2(|v|, w) in [0, pi]; accurate for small and large angles alike.
  return (2.0 * std::atan2(s, q.w()) / s) * q.vec();
}

Mat3 right_jacobian(const Vec3& theta) {
  const double t = theta.norm();
  const Mat3 k = cross_matrix(theta);
  double c1, c2;  // (1 - cos t) / t^2, (t - sin t) / t^3
  if (t < 1e-4) {
    c1 = 0.5 - t * t / 24.0;
    c2 = 1.0 / 6.0 - t * t / 120.0;
  } else {
    c1 = (1.0 - std::cos(t)) / (t * t);
    c2 = (t - std::sin(t)) / (t * t * t);
  }
  return Mat3::Identity() - c1 * k + c2 * k * k;
}

}  // namespace softrom
