// Linear tetrahedral mesh: rest geometry, per-element shape-function gradients, lumped mass.
#pragma once

#include <Eigen/Dense>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace softrom {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using VecX = Eigen::VectorXd;
using Tet = std::array<int32_t, 4>;

// Rest-state data of a linear tetrahedral mesh. Positions are stacked as a 3N vector
// (x0, y0, z0, x1, ...), the layout numpy's C-ordered (N, 3) arrays already have.
struct TetMesh {
  int num_nodes = 0;
  std::vector<Tet> tets;
  VecX rest;                      // 3N rest positions
  std::vector<Mat3> dm_inv;       // D_m^{-1} per tet (D_m = [X1-X0, X2-X0, X3-X0])
  std::vector<double> volume;     // rest volume per tet (> 0)

  // Builds the rest data. Throws std::invalid_argument naming the first bad tet (an index out
  // of range, a non-positive or degenerate volume) or the first node no tet uses.
  TetMesh(const VecX& rest_positions, std::vector<Tet> tetrahedra);

  int num_tets() const { return static_cast<int>(tets.size()); }
  double total_volume() const;
  // Lumped mass per node: each tet gives density * V / 4 to each of its nodes.
  VecX lumped_mass(double density) const;
  // Deformation gradient F = D_s D_m^{-1} of tet e for positions x (3N).
  Mat3 deformation_gradient(int e, const VecX& x) const;
};

}  // namespace softrom
