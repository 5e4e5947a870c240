// Full-space finite-element model: linear tetrahedra, stable Neo-Hookean material, lumped mass,
// gravity, Rayleigh damping, implicit Euler with Newton's method and a sparse direct solver.
#pragma once

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <memory>
#include <vector>

#include "material.h"
#include "tet_mesh.h"

namespace softrom {

using SpMat = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

struct StepStats {
  int iterations = 0;       // Newton iterations taken
  double step_norm = 0.0;   // max |dx| / dt of the last Newton update, m/s
  bool converged = false;
};

class FEMModel {
 public:
  FEMModel(const VecX& rest_positions, std::vector<Tet> tets, double youngs_modulus,
           double poisson_ratio, double density);

  const TetMesh& mesh() const { return mesh_; }
  const VecX& mass() const { return mass_; }          // per node, kg
  const StableNeoHookean& material() const { return material_; }
  double youngs_modulus() const { return youngs_; }
  double poisson_ratio() const { return poisson_; }
  double density() const { return density_; }

  // Elastic potential energy E(x) (J) of positions x (3N).
  double energy(const VecX& x) const;
  // Internal elastic forces f(x) = -dE/dx (N), 3N.
  VecX forces(const VecX& x) const;
  // Stiffness K(x) = -df/dx (3N x 3N, symmetric). With project=true each element block is
  // projected onto the PSD cone (what the integrator uses); otherwise it is exact.
  SpMat stiffness(const VecX& x, bool project) const;

  // One implicit Euler step of M dv/dt = f(x) + M g - D v with D = alpha M + beta K(x_n),
  // solved as the minimisation of the incremental potential by Newton's method with a
  // backtracking line search. Nodes with fixed[i] != 0 keep their position (zero velocity).
  void step(const VecX& x, const VecX& v, double dt, const std::vector<char>& fixed, VecX& x_out,
            VecX& v_out);
  const StepStats& last_step_stats() const { return stats_; }

  Vec3 gravity{0.0, 0.0, -9.81};
  double damping_alpha = 0.0;   // mass-proportional Rayleigh coefficient, 1/s
  double damping_beta = 0.005;  // stiffness-proportional Rayleigh coefficient, s
  double newton_tolerance = 1e-6;  // on max |dx| / dt, m/s
  int max_newton_iterations = 50;

 private:
  void assemble(const VecX& x, bool project, SpMat& k) const;
  double incremental_potential(const VecX& x, const VecX& x_tilde, const VecX& x_n,
                               const SpMat& damping_k, double dt) const;

  TetMesh mesh_;
  StableNeoHookean material_;
  double youngs_, poisson_, density_;
  VecX mass_;    // N
  VecX mass3_;   // 3N, each node's mass repeated per coordinate
  SpMat pattern_;                 // block sparsity of K, values unused
  std::vector<int> slots_;        // per tet, 144 positions into pattern_.valuePtr()
  std::vector<int> diag_slots_;   // per DOF, position of its diagonal entry
  Eigen::SimplicialLDLT<SpMat, Eigen::Lower, Eigen::AMDOrdering<int>> solver_;
  bool analysed_ = false;
  StepStats stats_;
};

}  // namespace softrom
