// Full-space finite-element model: linear tetrahedra, stable Neo-Hookean material, lumped mass,
// gravity, Rayleigh damping, implicit Euler with Newton's method and a sparse direct solver.
#pragma once

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <memory>
#include <mutex>
#include <vector>

#include "material.h"
#include "spd_system.h"
#include "tet_mesh.h"

namespace softrom {

// How step() solves its Newton systems. All four converge to the same implicit-Euler
// solution under the same tolerance; they differ in cost only.
enum class FEMSolver {
  // The step as first written, kept to measure against: numeric 9x9 eigen-projection of every
  // element Hessian that is not PSD, the full matrix assembled into fresh copies, a simplicial
  // LDL^T that re-permutes the matrix (AMD) at every factorisation, and one factorisation per
  // Newton iteration.
  kReference,
  // The fast step: closed-form projection (snh_eigensystem.h), the upper triangle assembled in
  // place on a pre-permuted pattern (spd_system.h), the symbolic analysis done once, the
  // last factorisation skipped when a bound proves the Newton step is already below tolerance,
  // and the exact K(x) (where it keeps the Newton matrix positive definite) once an iteration
  // fails to cut the step tenfold, where the projected K's Newton converges only linearly.
  // They differ in the sparse Cholesky only: supernodal (dense panels, the default and
  // fastest, supernodal_cholesky.h) or Eigen's simplicial LL^T / LDL^T.
  kSupernodalLLT,
  kSimplicialLLT,
  kSimplicialLDLT,
};

struct StepStats {
  int iterations = 0;       // Newton iterations taken
  int factorizations = 0;   // numeric factorisations of the Newton matrix
  int energy_evaluations = 0;  // incremental-potential evaluations in the line search
  double step_norm = 0.0;   // max |dx| / dt of the last Newton update, m/s
  bool converged = false;
  // Wall-clock seconds spent in each phase of the step (the profile of bench_fem.py).
  double assemble_s = 0.0;     // element stiffness, projection and scatter
  double gradient_s = 0.0;     // forces and the incremental potential's gradient
  double factorize_s = 0.0;    // numeric factorisation (and the one-off symbolic analysis)
  double solve_s = 0.0;        // triangular solves
  double line_search_s = 0.0;  // incremental-potential evaluations
};

class FEMModel {
 public:
  FEMModel(const VecX& rest_positions, std::vector<Tet> tets, double youngs_modulus,
           double poisson_ratio, double density);
  ~FEMModel();

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
  // projected onto the PSD cone (what the integrator uses: numerically for the reference
  // solver, in closed form otherwise); otherwise it is exact.
  SpMat stiffness(const VecX& x, bool project) const;

  // One implicit Euler step of M dv/dt = f(x) + M g - D v with D = alpha M + beta K(x_n),
  // solved as the minimisation of the incremental potential by Newton's method with a
  // backtracking line search. Nodes with fixed[i] != 0 keep their position (zero velocity).
  void step(const VecX& x, const VecX& v, double dt, const std::vector<char>& fixed, VecX& x_out,
            VecX& v_out);
  const StepStats& last_step_stats() const { return stats_; }

  FEMSolver solver() const { return solver_kind_; }
  void set_solver(FEMSolver kind) { solver_kind_ = kind; }

  // Held by the Python binding while step() runs without the GIL and while a setting
  // changes: two threads stepping one model would share its factorisation and scratch.
  std::mutex& mutex() const { return mutex_; }

  Vec3 gravity{0.0, 0.0, -9.81};
  double damping_alpha = 0.0;   // mass-proportional Rayleigh coefficient, 1/s
  double damping_beta = 0.005;  // stiffness-proportional Rayleigh coefficient, s
  double newton_tolerance = 1e-6;  // on max |dx| / dt, m/s
  int max_newton_iterations = 50;

 private:
  void step_reference(const VecX& x, const VecX& v, double dt, const std::vector<char>& fixed,
                      VecX& x_out, VecX& v_out);
  void step_fast(const VecX& x, const VecX& v, double dt, const std::vector<char>& fixed,
                 VecX& x_out, VecX& v_out);
  void assemble(const VecX& x, bool project, SpMat& k) const;
  // The PSD-projected stiffness's upper triangle on system_'s pattern, written into k.
  void assemble_projected_upper(const VecX& x, std::vector<double>& k) const;
  // The exact (unprojected) stiffness's upper triangle on the same pattern.
  void assemble_exact_upper(const VecX& x, std::vector<double>& k) const;
  double incremental_potential(const VecX& x, const VecX& x_tilde, const VecX& x_n,
                               const SpMat& damping_k, double dt) const;

  TetMesh mesh_;
  StableNeoHookean material_;
  double youngs_, poisson_, density_;
  VecX mass_;    // N
  VecX mass3_;   // 3N, each node's mass repeated per coordinate
  FEMSolver solver_kind_ = FEMSolver::kSupernodalLLT;
  StepStats stats_;

  // Reference path: the full pattern of K and the LDL^T that permutes it at every factorisation.
  SpMat pattern_;                 // block sparsity of K, values unused
  std::vector<int> slots_;        // per tet, 144 positions into pattern_.valuePtr()
  std::vector<int> diag_slots_;   // per DOF, position of its diagonal entry
  Eigen::SimplicialLDLT<SpMat, Eigen::Lower, Eigen::AMDOrdering<int>> solver_;
  bool analysed_ = false;

  // Fast path, built on its first step: the pre-permuted pattern, K(x) and K(x_n) on it.
  std::unique_ptr<SpdSystem> system_;
  std::vector<double> k_, k0_;
  mutable std::mutex mutex_;
};

}  // namespace softrom
