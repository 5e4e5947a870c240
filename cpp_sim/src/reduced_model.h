// Reduced-order soft body: q_r in the span of B_r (rigid translations + deformation columns),
// implicit Euler with Newton on the (M+3)-dimensional system, cubature for the elastic forces,
// staggered-projection ground contact with Coulomb friction, quadratic fluid drag, and
// batched rollouts on a thread pool.
#pragma once

#include <Eigen/Dense>
#include <array>
#include <vector>

#include "material.h"
#include "tet_mesh.h"

namespace softrom {

using MatX = Eigen::MatrixXd;
using RowMatX = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

enum class ContactModel { None = 0, Staggered = 1, Penalty = 2 };

struct ReducedConfig {
  double dt = 1.0 / 200.0;
  Vec3 gravity{0.0, 0.0, -9.81};
  ContactModel contact = ContactModel::Staggered;
  double friction = 0.8;          // Coulomb mu
  double ground_height = 0.0;     // plane z = ground_height, normal +z
  double contact_margin = 1e-3;   // m: nodes predicted closer than this are constraint rows
  double penalty_stiffness = 0.0; // N/m per node (0: chosen from the mass and dt)
  double fluid_density = 0.0;     // kg/m^3; > 0 switches quadratic drag on
  double drag_coefficient = 1.0;  // C_d
  double damping_alpha = 0.0;     // 1/s, on all reduced coordinates
  double damping_beta = 0.005;    // s, times the reduced stiffness K_r(q_n)
  double newton_tolerance = 1e-6; // on max |dv| (reduced velocity units), relative to 1
  int max_newton_iterations = 8;
  double contact_tolerance = 1e-4;  // m/s on contact-node velocities
  int max_stagger_iterations = 60;
  Vec3 direction{1.0, 0.0, 0.0};  // unit task direction d (reward d . v_com dt)
  double max_speed = 100.0;       // m/s: an RMS node speed above this counts as divergence
};

// Simulation state. `impulses` warm-starts the contact solver (per surface node, normal and two
// tangential), so it is part of the state: stepping from the same state is reproducible.
struct ReducedState {
  VecX q, qdot;
  VecX impulses;
};

struct StepInfo {
  int newton_iterations = 0;
  int stagger_iterations = 0;
  int normal_iterations = 0;   // semismooth Newton solves of the normal problem
  int friction_iterations = 0; // reweighted least-squares solves of the friction problem
  int active_rows = 0;       // contact candidates this step
  int contacts = 0;
  bool diverged = false;
};

class ReducedModel {
 public:
  // basis: 3N x (M + 6) mass-orthonormal: columns 0..2 rigid translations, 3..5 linearised
  // rotations about the rest centre of mass, then M deformation columns. The elastic energy
  // sees columns 3.. (what a linearised rotation does to the mesh, a turn plus a stretch of
  // theta^2 / 2, is what it stores energy for), so the model is the full-space model projected
  // on B_r; gravity loads only the translations; actuation B_c acts on deformation only.
  // cubature_elements / weights: tets and non-negative weights for the elastic force.
  ReducedModel(const TetMesh& mesh, const StableNeoHookean& material, const VecX& mass,
               const MatX& basis, const std::vector<int>& cubature_elements,
               const std::vector<double>& cubature_weights, const std::vector<int>& surface_nodes,
               const std::vector<std::array<int, 3>>& surface_faces);

  static constexpr int kTranslations = 3;
  static constexpr int kRigid = 6;  // translations + linearised rotations  // translations + linearised rotations
  int dim() const { return static_cast<int>(basis_cols_); }  // M + 6
  int elastic_dim() const { return dim() - kTranslations; }  // M + 3: rotations too
  int deformation_dim() const { return dim() - kRigid; }     // M
  int control_dim() const { return static_cast<int>(control_basis_.cols()); }
  int num_nodes() const { return num_nodes_; }
  int num_surface_nodes() const { return static_cast<int>(surface_nodes_.size()); }
  const std::vector<int>& surface_nodes() const { return surface_nodes_; }
  double total_mass() const { return total_mass_; }

  ReducedConfig config;
  void set_control_basis(const MatX& bc);  // M x C (deformation coordinates)
  const MatX& control_basis() const { return control_basis_; }

  ReducedState rest_state() const;
  // One step under control f_c (C). Never throws on divergence: it is reported in StepInfo.
  StepInfo step(ReducedState& s, const double* fc) const;

  // Elastic energy / reduced forces / reduced stiffness of the elastic coordinates q_e = q[3:]
  // (rotations and deformation, M + 3).
  double elastic_energy(const VecX& qd) const;
  VecX elastic_forces(const VecX& qd) const;
  MatX elastic_stiffness(const VecX& qd, bool project) const;

  // Full positions (N x 3 flattened) of a reduced configuration.
  VecX positions(const VecX& q) const;
  Vec3 com_velocity(const VecX& qdot) const;
  Vec3 com(const VecX& q) const;

  // Batched rollouts: controls (B, H, C) row-major; outputs rewards (B, H), final states.
  // `starts` holds 1 state (shared by all rollouts) or `batch` states (one each).
  void rollout(const std::vector<ReducedState>& starts, const double* controls, int batch,
               int horizon,
               int threads, double* rewards, double* final_q, double* final_qdot,
               double* final_impulses, unsigned char* diverged, double* com_traj,
               const MatX* observe = nullptr, double* observed = nullptr) const;

 private:
  struct Workspace;
  void elastic(const VecX& qd, bool project, double* energy, VecX* force, MatX* stiff) const;
  void drag(const VecX& q, const VecX& qdot, VecX& f, MatX& jac) const;
  int solve_contacts(const VecX& q, const MatX& a, VecX& v, VecX& impulses,
                     StepInfo& info) const;
  void penalty_contacts(const VecX& q, const VecX& v, VecX& f, MatX& jac) const;

  int num_nodes_ = 0;
  Eigen::Index basis_cols_ = 0;
  double total_mass_ = 0.0;
  Vec3 rest_com_;
  // Cubature: G = [G_1; ...; G_K] stacked (9K x M), G_e = d vec(F_e) / d q_d, and each
  // element's weight times rest volume. Stacking turns the reduced force and stiffness into
  // two matrix products instead of K small ones.
  RowMatX grad_;
  std::vector<double> wvol_;
  StableNeoHookean material_;
  // Surface: rows of B_r (3 x (M+3)) and rest positions of each surface node.
  std::vector<int> surface_nodes_;
  RowMatX surface_rows_;   // (3 n_s) x (M+3)
  VecX surface_rest_;      // 3 n_s
  std::vector<std::array<int, 3>> faces_;  // indices into surface nodes
  VecX node_mass_surface_; // lumped mass of each surface node
  MatX basis_;             // full B_r, for positions()
  VecX rest_;
  MatX control_basis_;     // M x C
  MatX k_rest_;            // K_r at rest (cubature), for Rayleigh damping
};

}  // namespace softrom
