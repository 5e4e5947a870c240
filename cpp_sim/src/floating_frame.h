// The floating frame's kinematics and kinetic terms (docs/FLOATING_FRAME.md).
//
// Node i is at x_i = c + R r_i, r_i = X_i + U_i z: X_i its rest position about the centre of
// mass, U_i its rows of B_r's M deformation columns (mass-orthonormal, and mass-orthogonal to
// the six rigid modes, which the model's basis validation guarantees: sum m U = 0 keeps c the
// centre of mass, sum m X x U = 0 makes the frame the mean-axis one, which is Buckens' best fit).
// Velocities: u = c' (world), omega (body frame), w = z'. The kinetic energy is
//
//   T = 1/2 m |u|^2 + 1/2 omega^T I(z) omega + omega^T S(z) w + 1/2 |w|^2,
//
// I(z) = sum m [r]x^T [r]x = tr(J) 1 - J with J(z) = sum m r r^T (quadratic in z) and
// S(z) = sum m [r]x U (linear in z). Their coefficients are sums over the nodes formed once
// (FloatingCoefficients), so every kinetic term below costs O(M^2), whatever the mesh.
//
// Indices: a, b the three axes (a pair as 3 a + b), k, l the deformation coordinates.
#pragma once

#include <Eigen/Dense>
#include <array>
#include <cmath>

#include "tet_mesh.h"

namespace softrom {

struct FloatingCoefficients {
  Mat3 j0 = Mat3::Zero();             // sum m X X^T
  std::array<VecX, 9> a;              // a[3a+b][k] = sum m X_a U_bk
  std::array<Eigen::MatrixXd, 9> c;   // c[3a+b](k, l) = sum m U_ak U_bl   (c[3b+a] = c[3a+b]^T)
  std::array<Eigen::MatrixXd, 3> c_pair;  // c[3a+b] + c[3b+a] for (a, b) = (0, 1), (0, 2), (1, 2)
  std::array<Eigen::MatrixXd, 3> y;   // y[a](k, l) = (sum m U_k x U_l)_a  (antisymmetric)
  std::array<VecX, 3> s0;             // s0[a][l] = (sum m X x U_l)_a      (0 at a mean-axis basis)
  double gyration = 0.0;  // sqrt(largest eigenvalue of I(0) / m), m: the Newton test's length

  // rest: 3N rest positions about the centre of mass; mass: N; u: 3N x M.
  static FloatingCoefficients build(const VecX& rest, const VecX& mass, double total_mass,
                                    const Eigen::MatrixXd& u);
};

// The inertia, coupling and their z-derivatives at one configuration z.
struct FloatingBody {
  Mat3 inertia;                                 // I(z)
  Eigen::Matrix<double, 3, Eigen::Dynamic> s;   // S(z), 3 x M
  std::array<VecX, 9> d;                        // d[3a+b][k] = dJ_ab / dz_k (D_k, symmetric)
  std::array<VecX, 9> cz;                       // scratch: C_ab z (evaluate's) ...
  VecX sz;                                      // ... and Y_a^T z

  void evaluate(const FloatingCoefficients& co, const Eigen::Ref<const VecX>& z);
  double trace_d(Eigen::Index k) const { return d[0][k] + d[4][k] + d[8][k]; }
  // dI/dz_k applied to a 3-vector: tr(D_k) v - D_k v.
  Vec3 d_inertia(Eigen::Index k, const Vec3& v) const {
    Vec3 out;
    for (int a = 0; a < 3; ++a)
      out[a] = trace_d(k) * v[a] - (d[3 * a][k] * v[0] + d[3 * a + 1][k] * v[1] +
                                    d[3 * a + 2][k] * v[2]);
    return out;
  }
};

// Rotations as rotation vectors theta (R = exp([theta]x)), kept at |theta| <= pi.
Mat3 rotation_matrix(const Vec3& theta);
// The rotation vector of exp([theta]x) exp([phi]x), |result| <= pi.
Vec3 compose_rotations(const Vec3& theta, const Vec3& phi);
// The right Jacobian of SO(3): exp(theta + d) = exp(theta) exp(J_r(theta) d) to first order.
Mat3 right_jacobian(const Vec3& theta);
inline Mat3 cross_matrix(const Vec3& v) {
  Mat3 m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

}  // namespace softrom
