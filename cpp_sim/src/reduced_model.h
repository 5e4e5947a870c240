// Reduced-order soft body: x = X + B_r q_r (B_r: 3 rigid translations, 3 linearised rotations,
// M deformation columns), implicit Euler on the (M + 6)-dimensional system, cubature for the
// elastic forces (elements e with weights w_e), actuation f_r = B_c f_c on the deformation
// coordinates, staggered-projection ground contact with Coulomb friction (normal and friction
// halves), quadratic fluid drag, and batched rollouts on a persistent thread pool.
//
// The implementation is split by job:
//   reduced_model.cpp     construction, kinematics (positions, centre of mass)
//   reduced_elastic.cpp   cubature energy, forces and stiffness (the hot kernels)
//   reduced_dynamics.cpp  the implicit step: reference Newton and the fast quasi-Newton
//   reduced_contact.cpp   contact candidates (then staggered_projection.cpp: staggered
//                         projection, normal LDP + friction), penalty ground
//   reduced_drag.cpp      quadratic surface drag
//   reduced_rollout.cpp   batched rollouts on the thread pool (thread_pool.h)
//   reduced_floating.cpp  the floating frame's step (config.frame = Floating; kinematics
//                         and kinetic coefficients in floating_frame.h)
#pragma once

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "floating_frame.h"
#include "material.h"
#include "nnls.h"
#include "scratch.h"
#include "tet_mesh.h"

namespace softrom {

using MatX = Eigen::MatrixXd;
using RowMatX = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

enum class ContactModel { None = 0, Staggered = 1, Penalty = 2 };

// Reference: exact Newton (stiffness rebuilt at every iteration), QR-based NNLS, the contact
// metric the last Newton matrix; kept to check the fast path against.
// Fast (default): quasi-Newton from the rest-stiffness matrix A_0 with BFGS updates and an
// Armijo line search on the incremental potential, the stiffness rebuilt only when the
// iteration stalls (and once where a step with contact ends: the contact metric); the same
// staggered projection as the reference, with a Gram-Cholesky NNLS (Givens downdates) and the
// friction step solved in the loaded rows' space when they are fewer than the coordinates.
enum class Solver { Reference = 0, Fast = 1 };

// How the rigid motion is represented (docs/FLOATING_FRAME.md).
// Linear (default): x = X + B_r q, the rotations linearised (every recorded figure is this
// model's). Floating: x_i = c + R (X_i + U_i z) with an exact rotation R, q = (sqrt(m) (c - c_0),
// the rotation vector theta of R (|theta| <= pi), z) and qdot = (sqrt(m) c', the body-frame
// angular velocity omega, z'); actuation follows the body, torque-free, so in free flight the
// angular momentum is kept to the Newton tolerance. Gravity, Rayleigh damping, drag and both
// grounds apply.
enum class Frame { Linear = 0, Floating = 1 };

// Every setting of a reduced model, in one place: the binding exposes this struct as
// `ReducedConfig` and the model's settings as its fields.
struct ReducedConfig {
  double dt = 1.0 / 200.0;
  Vec3 gravity{0.0, 0.0, -9.81};
  ContactModel contact = ContactModel::Staggered;
  Solver solver = Solver::Fast;
  double friction = 0.8;          // Coulomb mu
  double ground_height = 0.0;     // plane z = ground_height, normal +z
  double contact_margin = 1e-3;   // m: nodes predicted closer than this are constraint rows
  double penalty_stiffness = 0.0; // N/m per node (0: from the body's weight, see penalty_contacts)
  double fluid_density = 0.0;     // kg/m^3; > 0 switches quadratic drag on
  double drag_coefficient = 1.0;  // C_d
  double damping_alpha = 0.0;     // 1/s, on all reduced coordinates
  double damping_beta = 0.005;    // s, times the reduced stiffness K_r(rest)
  double newton_tolerance = 1e-6; // on max |dv| / sqrt(m), m/s
  int max_newton_iterations = 30;
  double contact_tolerance = 1e-4;  // m/s on contact-node velocities
  // eps of the smoothed friction law |v_t|_eps = sqrt(|v_t|^2 + eps^2), m/s; 0: contact_tolerance
  // (as before the setting existed). Separate so that a tighter stop is not other friction.
  double friction_smoothing = 0.0;
  double friction_eps() const {
    return friction_smoothing > 0.0 ? friction_smoothing : contact_tolerance;
  }
  int max_stagger_iterations = 60;
  double stabilization = 0.2;     // Baumgarte fraction of a penetration removed per step
  // The least normal velocity a node at height z above the ground may end a step with: it may
  // reach the plane, and a penetrating node rises by a fraction `stabilization` of its depth.
  double normal_velocity_bound(double z) const {
    return z >= 0.0 ? -z / dt : -stabilization * z / dt;
  }
  Vec3 direction{1.0, 0.0, 0.0};  // unit task direction d (reward d . v_com dt)
  double max_speed = 100.0;       // m/s: an RMS node speed above this counts as divergence
  bool profile = false;           // time the parts of each step into StepInfo (a few % cost)
  Frame frame = Frame::Linear;
};

// One loaded surface node's penalty force, its rows of W (J_pen = -W^T W) and the row of its
// friction's coupling to the normal force, summed by both frames' penalty grounds
// (reduced_contact.cpp has the law).
void penalty_node_load(double mu, double fn, double jn, const double* rx, const double* ry,
                       const double* rz, const double* v, Eigen::Index m, Eigen::Index mp,
                       double* f, double* w, double* coupling);
// jac (m x m) += C = A^T N, the friction's coupling to the normal force of `loaded` nodes:
// A's rows the nodes' coupling rows (penalty_node_load's, mp apart), N's their normal rows of
// W (every third row of w).
void add_penalty_coupling(const double* coupling, const double* w, Eigen::Index loaded,
                          Eigen::Index m, Eigen::Index mp, MatX& jac);

// Simulation state. `impulses` warm-starts the contact solver (per surface node, two tangential
// then the normal), so it is part of the state: stepping from the same state is reproducible.
struct ReducedState {
  VecX q, qdot;
  VecX impulses;
};

struct StepInfo {
  int newton_iterations = 0;
  int stiffness_evaluations = 0;  // reduced stiffness K_r(q) builds this step
  int stagger_iterations = 0;
  int normal_iterations = 0;      // normal half-steps (by NNLS or on the held loaded set)
  int friction_iterations = 0;    // reweighted least-squares solves of the friction problem
  int active_rows = 0;            // contact candidates this step
  int contacts = 0;  // surface nodes loaded (lambda_n > 0) by the staggered projection; else 0
  bool converged = true;          // Newton reached newton_tolerance
  bool contact_converged = true;  // staggering reached contact_tolerance, NNLS within its cap
  bool diverged = false;
  // With config.profile: seconds spent in each part of the step.
  double time_dynamics = 0.0, time_drag = 0.0, time_normal = 0.0, time_friction = 0.0;
  // With config.profile, staggered projection's course, a token per event (profiling allocates
  // for it; the plain step does not):
  //   N<n> / S<n>  a stagger's normal half by NNLS over every candidate / on the held loaded
  //                set, n nodes loaded after it; (+a-b) when a nodes entered and b left the
  //                previous stagger's set (the first stagger: the warm start's);
  //   W<i> / w<i><why>  the held-set Newton reached the root in i steps / failed after i
  //                (why: l a node would leave the set, r a load not positive, s a singular
  //                step, c the iteration cap);   J  an Aitken jump;
  //   ok / cap     the end: converged / at max_stagger_iterations (a last normal solve follows);
  //   n            after ok: a last normal solve, the friction half having left a candidate
  //                below its bound by more than contact_tolerance;
  //   R            the step solved again from v*, warm-started: a node outside the candidates
  //                ended below its bound, or (floating frame) the height drift moved.
  // Empty when no node is a contact candidate.
  std::string stagger_trace;
};

// Adds the seconds since construction to `*target` on destruction (when target is not null).
class ScopedTimer {
 public:
  explicit ScopedTimer(double* target) : target_(target) {
    if (target_) start_ = std::chrono::steady_clock::now();
  }
  ~ScopedTimer() { stop(); }
  void stop() {
    if (target_)
      *target_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    target_ = nullptr;
  }

 private:
  double* target_;
  std::chrono::steady_clock::time_point start_;
};

class StaggeredProjection;  // the contact solve and its buffers (staggered_projection.h)

class ReducedModel;

// Scratch memory for one model's steps, reused from step to step by one caller at a time (a
// Python step, a rollout's worker: as MuJoCo's rollout gives each thread its own mjData): the
// dynamics' buffers, the contact solve's and its least-distance (NNLS) programmes'. The
// contact buffers change size with each step's candidates and loaded sets, so they keep their
// memory as they shrink (scratch.h): once a workspace has seen its largest sizes, the fast
// solver's step allocates nothing.
//
// A workspace serves the model that lent it (ReducedModel::lend_workspace) and no other
// (step() asserts it in debug builds). Its buffers carry no data from one step to the next (a
// step sizes and writes each before it reads it), but they keep their sizes, which are that
// model's: shared by two models, a workspace would reallocate at every switch between them,
// and a buffer read before it was sized would hold the other model's data. The model keeps
// the workspaces it lends, so they go with it.
struct Workspace {
  Workspace();
  ~Workspace();
  Workspace(const Workspace&) = delete;
  Workspace& operator=(const Workspace&) = delete;

  const ReducedModel* lender = nullptr;  // the model whose steps it serves (lend_workspace)

  // The step's loads (step_loads, penalty_contacts): f_ext (gravity + B_c f_c), the drag force
  // and its Jacobian J_d, the penalty force and its Jacobian's symmetric part and (reference
  // solver) the friction's coupling to the normal force (the Jacobian is their sum).
  VecX f_ext, f_drag, f_pen;
  MatX j_drag, j_pen, j_pen_coupling;
  // The Newton iteration (reduced_dynamics.cpp): elastic force f_e and stiffness K_r at the
  // iterate, the implicit matrix A, the residual r (reference) or the gradient g of Phi
  // (fast), the step dv; the fast step's inverse estimate H, its line search's trial point
  // and BFGS pair s = v_trial - v, y = g_trial - g (and H y).
  VecX f_el, r, g, g_trial, v_trial, dv, s, y, hy;
  MatX k_el, a, h_inv;
  VecX v, tmp_e;  // the fast step's velocity iterate and elastic coordinates
  Eigen::LLT<MatX> a_llt;  // the fast step's factor of A (its last stiffness refresh)
  VecX q_next, impulses_next;  // finish_step's candidate state, swapped in when it is good
  // The fast elastic kernels' scratch (reduced_elastic.cpp).
  VecX f_minus_i;    // vec F_k - vec I of every cubature element (the stiffness's)
  VecX force_lanes;  // snh_force's per-lane partial sums
  RowMatX hg;   // elastic_stiffness_fast's rows of H G for a group of elements ...
  MatX k_pad;   // ... and the Gram sum G^T H G, padded to a multiple of 4 columns
  // The drag Jacobian as a factor, J_d = -W W^T (W: M + 6 rows, one column per face advancing
  // into the fluid, drag_cols of them), for the fast solver's matrix-free products; drag_fast
  // pads its rows with zeros to a multiple of 4.
  MatX drag_w;
  Eigen::Index drag_cols = 0;
  VecX drag_xs, drag_vs, drag_coef, drag_pad, drag_wwg, drag_normals;
  ScratchVec drag_wg;  // W^T g: one entry per advancing face, a number that changes each step
  std::vector<std::ptrdiff_t> drag_faces;  // (drag_fast's and the potential's scratch)
  bool drag_jacobian_formed = false;
  NnlsWorkspace nnls;  // the contact solve's least-distance programmes, one per stagger
  std::unique_ptr<StaggeredProjection> contact;  // made by the first contact solve
  std::vector<int> contact_active;     // the step's contact candidates (surface node ids) ...
  std::vector<double> contact_gap;     // ... and their heights above the ground
  std::vector<char> contact_member;    // (add_missed_candidates' scratch)
  VecX contact_v_free;                 // the contact-free velocity a contact solve starts from
  // N q and N v (N: the surface nodes' normal rows) of the step's end, from near_ground for
  // the contact solve that follows it (two products over every surface node, ~0.1 M
  // instructions each on the quadruped); cleared at each step's start.
  VecX ground_z, ground_vn;
  bool ground_rows_ready = false;
  // The floating frame's Newton iteration (reduced_floating.cpp): the body's inertia and
  // coupling at the iterate, its iterate x = (u, omega, w), residual, Jacobian and step, and
  // the terms they are built from (fl_yw: dS/dz_k w; fl_yf, fl_ya, fl_sti: the actuation's
  // Jacobian, Y_a f, sum_b a_b Y_b and S^T I^-1; fl_turned_drag: exp(-h omega') times J_d's
  // torque rows).
  FloatingBody fl_body;
  VecX fl_x, fl_trial, fl_r, fl_dx, fl_z, fl_qe, fl_fe, fl_fa, fl_p0, fl_g, fl_q, fl_load;
  VecX fl_best;  // the floating Newton's iterate of least residual (an unconverged step's answer)
  VecX fl_tmp, fl_dv;
  std::array<VecX, 3> fl_yw, fl_yf;
  MatX fl_jac, fl_k, fl_e, fl_ya, fl_sti;
  Eigen::Matrix<double, 3, Eigen::Dynamic> fl_turned_drag;
  Eigen::PartialPivLU<MatX> fl_lu;
  // Its surface (floating_surface, floating_node_velocities, floating_drag,
  // floating_contacts): the surface nodes' body and world positions at the step's start,
  // their world velocities, U w's scratch, the drag law's buffer, the contact candidates'
  // height drift over the step (floating_contacts) and their velocity rows.
  VecX fl_rs, fl_xs, fl_vs, fl_uw, fl_speed;
  std::vector<double> contact_drift;
  MatX fl_gram;  // floating_drag_fast's W W^T (lower triangle)
  RowMatX fl_rows;
  // The penalty ground's force and Jacobian at the iterate (floating_penalty), the rows of
  // its friction's coupling to the normal force, and the Jacobian of the load it shares with
  // the drag (J_d + J_pen, when both act).
  VecX fl_pen;
  MatX fl_pen_jac, fl_load_jac;
  ScratchRowMat fl_pen_coupling;
  // The step's normal rows of every surface node (column-major), their normal velocities at
  // the iterate, and which nodes have their rows in fl_rows this step.
  MatX fl_pen_normal_cols;
  VecX fl_pen_vn;
  Mat3 fl_pen_rot;  // R at the step's start
  std::vector<char> fl_pen_rows_formed;
  // The Newton step on the residual (step_reference: the reference solver, and penalty
  // contact's): the LDL^T of A (with penalty contact, of A's symmetric part; the reference
  // solver then factors A itself by LU), the iterate's elastic coordinates and generalised
  // position, the residual's products and v - v_n, and the penalty line search's trial point
  // (elastic coordinates, elastic and penalty forces, residual).
  Eigen::LDLT<MatX> ref_ldlt;
  Eigen::PartialPivLU<MatX> ref_lu;
  VecX ref_qe, ref_q, ref_prod, ref_dw, ref_qe_trial, ref_f_trial, ref_f_pen_trial, ref_r_trial;
  // penalty_contacts': the surface nodes' positions and velocities (the fast solver's: their
  // heights and normal velocities), a node's scaled normal row and friction force, and its
  // tangent rows times the friction Jacobian (reference); the fast solver's factor W of
  // J_pen = -W^T W (three rows per loaded node, padded to a multiple of 4 columns) and W^T W,
  // and the coupling rows a (one per loaded node: penalty_node_load's).
  VecX pen_xs, pen_vs, pen_row, pen_ft;
  Eigen::Matrix<double, Eigen::Dynamic, 2> pen_at;
  ScratchRowMat pen_w, pen_coupling;
  Eigen::Index pen_loaded = 0;  // (the fast solver's loaded nodes: rows of pen_coupling)
  VecX pen_nx, pen_cx, pen_rhs;  // C x's N x, C x, and a refinement's right-hand side
  MatX pen_gram;
};

// What one call reads from the model besides its constant data: copied at entry, so a call
// running without the GIL never sees another thread's writes to the settings or B_c.
struct StepInputs {
  ReducedConfig config;
  MatX control_basis;  // B_c, M x C (f_r = B_c f_c on the deformation coordinates)
  // A_0^-1 = (I + (h^2 + h beta) K_0 + h alpha I)^-1, the fast step's starting inverse, shared
  // with the model's cache (ReducedModel::rest_newton_inverse; never written once made). Null
  // where the step does not start from it (the reference solver, penalty contact).
  std::shared_ptr<const MatX> rest_newton_inverse;
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
  static constexpr int kRigid = 6;  // translations + linearised rotations
  int dim() const { return static_cast<int>(basis_cols_); }  // M + 6
  int elastic_dim() const { return dim() - kTranslations; }  // M + 3: rotations too
  int deformation_dim() const { return dim() - kRigid; }     // M
  int control_dim() const { return static_cast<int>(control_basis_.cols()); }
  int num_nodes() const { return num_nodes_; }
  int num_surface_nodes() const { return static_cast<int>(surface_nodes_.size()); }
  int num_cubature_elements() const { return static_cast<int>(wvol_.size()); }
  const std::vector<int>& surface_nodes() const { return surface_nodes_; }
  double total_mass() const { return total_mass_; }

  ReducedConfig config;
  void set_control_basis(const MatX& bc) { control_basis_ = bc; }  // M x C, validated by caller
  const MatX& control_basis() const { return control_basis_; }
  StepInputs inputs() const;
  // Whether step() takes the fast quasi-Newton path (step_fast), which starts from A_0^-1.
  static bool uses_fast_step(const ReducedConfig& cfg) {
    // Penalty contact is not a potential force (damping, friction), so it keeps the Newton
    // solve on the residual; it still gets the fast kernels when solver = fast. The floating
    // frame has its own step (step_floating), which does not start from A_0.
    return cfg.frame == Frame::Linear && cfg.solver == Solver::Fast &&
           cfg.contact != ContactModel::Penalty;
  }

  ReducedState rest_state() const;

  // A workspace of this model's, lent until the lease ends (it must not outlive the model):
  // one it lent before and got back when there is one (its buffers warm), else a new one. As
  // many exist as callers have held at once. Safe to call from several threads.
  class WorkspaceLease {
   public:
    ~WorkspaceLease();  // gives the workspace back
    WorkspaceLease(const WorkspaceLease&) = delete;
    WorkspaceLease& operator=(const WorkspaceLease&) = delete;
    Workspace& operator*() const { return *ws_; }

   private:
    friend class ReducedModel;
    WorkspaceLease(const ReducedModel& model, std::unique_ptr<Workspace> ws)
        : model_(model), ws_(std::move(ws)) {}
    const ReducedModel& model_;
    std::unique_ptr<Workspace> ws_;
  };
  WorkspaceLease lend_workspace() const;

  // One step under control f_c (C entries; may be null when C = 0), in a workspace this model
  // lent. Never throws on divergence: it is reported in StepInfo.
  StepInfo step(const StepInputs& in, ReducedState& s, const double* fc, Workspace& ws) const;

  // Elastic energy / reduced forces / reduced stiffness of the elastic coordinates q_e = q[3:]
  // (rotations and deformation, M + 3). The energy by the reference kernel, the forces and
  // the unprojected stiffness by the fast ones; project = true clamps each element's dP/dF
  // to PSD (reference kernel), which neither solver's step does (they project the summed K_r).
  double elastic_energy(const VecX& qe) const;
  double elastic_energy_fast(const VecX& qe) const;  // the fast kernels' (kernels::snh_force)
  VecX elastic_forces(const VecX& qe) const;
  MatX elastic_stiffness(const VecX& qe, bool project) const;
  // min det F over every tetrahedron of the mesh at configuration q (M + 6): the smallest
  // deformed-to-rest volume ratio J. J <= 0: an element is inverted. (The cubature's elements
  // alone would miss some: a few inverted tetrahedra of a soft tripod lie outside it.)
  double min_volume_ratio(const VecX& q) const;

  // Full positions (N x 3 flattened) of a reduced configuration, and node velocities, in the
  // frame config.frame says.
  VecX positions(const VecX& q) const;
  VecX velocities(const VecX& q, const VecX& qdot) const;
  // For the tests: the linear frame's penalty ground force at q = q_n + h v, its Jacobian in v
  // as the solver forms it (symmetric part, and the friction's coupling C), and, when x is not
  // null, C x as step_reference's Newton step applies it (the fast solver's through its rows).
  void penalty_load_for_tests(const StepInputs& in, const VecX& q_n, const VecX& v,
                              const VecX* x, VecX& force, MatX& symmetric, MatX& coupling,
                              VecX& coupling_x, Workspace& ws) const;
  // The floating frame's step residual at x = (u', omega', w') from s under f_c (C entries), and
  // its Jacobian: what step_floating's Newton iteration solves, for the tests.
  void floating_residual_for_tests(const StepInputs& in, const ReducedState& s, const VecX& fc,
                                   const VecX& x, MatX& residual, MatX& jacobian,
                                   Workspace& ws) const;
  Vec3 com_velocity(const VecX& qdot) const;
  Vec3 com(const VecX& q) const;

  // Batched rollouts: controls (B, H, C) row-major; outputs rewards (B, H), final states.
  // `starts` holds 1 state (shared by all rollouts) or `batch` states (one each).
  struct RolloutOutputs {
    double* rewards = nullptr;         // B x H
    double* final_q = nullptr;         // B x dim
    double* final_qdot = nullptr;      // B x dim
    double* final_impulses = nullptr;  // B x 3 n_s
    unsigned char* diverged = nullptr; // B
    unsigned char* converged = nullptr;// B: every step's Newton and contact solve converged
    int* good_steps = nullptr;         // B: the steps before the one that diverged (H if none)
    double* com = nullptr;             // B x H x 3 (optional)
    const MatX* observe = nullptr;     // P x dim (optional)
    double* observed = nullptr;        // B x H x P
    // Asked on the calling thread about every ThreadPool::kPollInterval; once it returns true
    // every rollout stops at its next step and the outputs are incomplete (Ctrl-C).
    const std::function<bool()>* interrupt = nullptr;
  };
  void rollout(const StepInputs& in, const std::vector<ReducedState>& starts,
               const double* controls, int batch, int horizon, int threads,
               const RolloutOutputs& out) const;

 private:
  // Cubature kernels (reduced_elastic.cpp): elastic_reference by per-element Eigen products
  // (the reference solver's, and the stiffness with per-element projection); the others on
  // the interleaved / padded copies of G through dense_kernels.h (the fast solver's).
  void elastic_reference(const VecX& qe, bool project, double* energy, VecX* force,
                         MatX* stiff) const;
  void deformation_gradients_fast(const VecX& qe, Workspace& ws) const;
  double elastic_energy_force(const VecX& qe, VecX& force, Workspace& ws) const;
  void elastic_stiffness_fast(const VecX& qe, MatX& stiff, Workspace& ws) const;

  // A_0^-1 for cfg's dt, damping_alpha and damping_beta, from the cache below (formed when one
  // of them differs from the last call's); null where A_0 has no Cholesky factor.
  std::shared_ptr<const MatX> rest_newton_inverse(const ReducedConfig& cfg) const;
  StepInfo step_reference(const StepInputs& in, ReducedState& s, const double* fc,
                          Workspace& ws) const;
  StepInfo step_fast(const StepInputs& in, ReducedState& s, const double* fc,
                     Workspace& ws) const;
  // The floating frame's step (reduced_floating.cpp): Newton on the momentum-form implicit
  // Euler residual, LU-factored (the gyroscopic terms make it unsymmetric); exact with solver =
  // reference, its stiffness frozen at K_0 with solver = fast (the file's comment).
  StepInfo step_floating(const StepInputs& in, ReducedState& s, const double* fc,
                         Workspace& ws) const;
  // The floating frame's residual at x = (u', omega', w') into ws.fl_r, and with `jacobian`
  // its Jacobian into ws.fl_jac (the file's comment has the equations). The Jacobian's
  // stiffness is K(z') evaluated at x into ws.fl_k when `stiffness` is null, else that
  // (elastic_dim square) matrix: the fast solver's frozen K.
  void floating_residual(const StepInputs& in, const ReducedState& s, const Vec3& pi0,
                         const VecX& x, bool jacobian, const MatX* stiffness,
                         Workspace& ws) const;
  // K(z') at x = (u', omega', w') into ws.fl_k, by the solver's kernels.
  void floating_stiffness(const ReducedConfig& cfg, const ReducedState& s, const VecX& x,
                          Workspace& ws) const;
  // The surface nodes' body positions r_i (ws.fl_rs) and world positions (ws.fl_xs) at q; the
  // drag and the contact solve start from them. floating_node_velocities: their world
  // velocities at (q, qdot) into out (3 n_s; ws.fl_uw is scratch).
  void floating_surface(const VecX& q, Workspace& ws) const;
  // out (3 n_s) = the surface rows' deformation columns times a's deformation entries.
  void deformation_rows_times(const VecX& a, VecX& out) const;
  void floating_node_velocities(const VecX& q, const VecX& qdot, VecX& out, Workspace& ws) const;
  // The surface nodes' world velocity rows [I / sqrt(m), -R [r_c]x, R U_c] at the step's start
  // (after floating_surface, R the rotation of s.q) into ws.fl_rows, for the surface nodes in
  // `nodes`; floating_velocity_row: node c's, given R (ws.fl_rows already sized
  // 3 n_s x (M + 6)).
  void floating_velocity_rows(const ReducedState& s, const std::vector<int>& nodes,
                              Workspace& ws) const;
  void floating_velocity_row(const Mat3& rot, Eigen::Index c, Workspace& ws) const;
  // The penalty ground's set-up at the step's start (after floating_surface): every surface
  // node's normal velocity row e_z^T B_i, column-major, into ws.fl_pen_normal_cols, and no
  // node's full rows formed yet (floating_penalty forms a loaded node's on first use).
  void floating_penalty_start(const ReducedState& s, Workspace& ws) const;
  // The penalty ground's generalised force at x = (u', omega', w') into ws.fl_pen, and with
  // `jacobian` its derivative into ws.fl_pen_jac: penalty_contacts' law on the surface rows at
  // the step's start, a node's height after the step predicted by them, as the staggered
  // ground's candidates are. The derivative is exact: -W^T W and the friction's coupling to
  // the normal force (penalty_node_load).
  void floating_penalty(const ReducedConfig& cfg, const VecX& x, bool jacobian,
                        Workspace& ws) const;
  // The drag at the step's start into ws.f_drag, ws.j_drag (after floating_surface).
  // (With solver = fast by floating_drag_fast: the same sums, rounded differently.)
  void floating_drag(const ReducedConfig& cfg, const ReducedState& s, Workspace& ws) const;
  void floating_drag_fast(const ReducedConfig& cfg, const ReducedState& s, Workspace& ws) const;
  // The floating frame's staggered projection of v (in: contact-free, out: projected) with
  // the surface rows at s.q; returns the staggers (ws.impulses_next gets the impulses).
  // `stiffness_at_v`: ws.fl_k holds exact Newton's K(z') near v already (else it is
  // evaluated at v when a node is a candidate).
  int floating_contacts(const StepInputs& in, const ReducedState& s, VecX& v, VecX& impulses,
                        bool stiffness_at_v, Workspace& ws, StepInfo& info) const;
  void external_forces(const StepInputs& in, const double* fc, VecX& f_ext) const;
  void step_loads(const StepInputs& in, const ReducedState& s, const double* fc, bool jacobian,
                  Workspace& ws, StepInfo& info) const;
  bool finish_step(const StepInputs& in, ReducedState& s, VecX& v, const MatX& a,
                   const Eigen::LLT<MatX>& a_llt, Workspace& ws, StepInfo& info) const;

  // True when a surface node is a contact candidate at (q, v); leaves N q and N v in ws for
  // solve_contacts.
  bool near_ground(const ReducedConfig& cfg, const VecX& q, const VecX& v, Workspace& ws) const;
  // Surface node c's height above the ground, from z_c = (N q)_c (N: normal_rows_).
  double ground_gap(const ReducedConfig& cfg, Eigen::Index c, double z_c) const {
    return surface_rest_[3 * c + 2] + z_c - cfg.ground_height;
  }
  // The contact candidate test, near_ground's and solve_contacts': a node within the contact
  // margin of the ground, or that would reach it within two steps at its normal velocity v_n.
  static bool contact_candidate(const ReducedConfig& cfg, double gap, double v_n) {
    return gap + 2.0 * cfg.dt * std::min(v_n, 0.0) < cfg.contact_margin;
  }
  // The step's contact candidates (contact_candidate) into ws.contact_active (surface node
  // ids) and ws.contact_gap, from gap_of(c) and vn_of(c), surface node c's height above the
  // ground and normal velocity; returns their count (info.active_rows), and with none clears
  // `impulses`. Both frames' contact solves start here.
  template <class Gap, class NormalVelocity>
  int pick_candidates(const ReducedConfig& cfg, Gap gap_of, NormalVelocity vn_of,
                      VecX& impulses, Workspace& ws, StepInfo& info) const {
    std::vector<int>& active = ws.contact_active;
    std::vector<double>& gap = ws.contact_gap;
    active.clear();
    gap.clear();
    for (int c = 0; c < num_surface_nodes(); ++c) {
      const double z = gap_of(c);
      if (contact_candidate(cfg, z, vn_of(c))) {
        active.push_back(c);
        gap.push_back(z);
      }
    }
    info.active_rows = static_cast<int>(active.size());
    if (active.empty()) impulses.setZero();
    return info.active_rows;
  }
  // Drag at (q, qdot): the force f, the factor W of its Jacobian J_d = -W W^T (columns
  // 0..cols-1 of w), and J_d itself when jac is not null.
  void drag(const ReducedConfig& cfg, const VecX& q, const VecX& qdot, VecX& f, MatX* jac,
            MatX& w, Eigen::Index& cols) const;
  // The drag law on world surface positions xs and velocities vs (3 n_s each, surface node
  // order); column(t, n, out) writes face t's velocity rows (the mean of its three nodes')
  // times its unit normal n, the generalised direction of a force along n: drag() from the
  // basis's constant rows, the floating frame from the body's rows at q.
  using FaceColumn = std::function<void(Eigen::Index, const Vec3&, Eigen::Ref<VecX>)>;
  // coef_scratch, speed_scratch: buffers it may keep (a workspace's), else its own.
  void drag_on_surface(const ReducedConfig& cfg, const VecX& xs, const VecX& vs,
                       const FaceColumn& column, VecX& f, MatX* jac, MatX& w,
                       Eigen::Index& cols, VecX* coef_scratch = nullptr,
                       VecX* speed_scratch = nullptr) const;
  // The same into ws.f_drag, ws.drag_w (rows padded to a multiple of 4) and ws.drag_cols,
  // through the dense kernels (fast solver).
  void drag_fast(const ReducedConfig& cfg, const VecX& q, const VecX& qdot, Workspace& ws) const;
  // drag_fast's face pass, shared with floating_drag_fast: over the surface's faces at node
  // positions x and velocities v (3 n_s each, in one frame), each advancing face's scaled
  // normal (ws.drag_normals), force coefficient (ws.drag_coef) and id (ws.drag_faces), and
  // W's columns U_t^T n from its three padded rows (ws.drag_w); returns how many advance.
  Eigen::Index advancing_faces(const double* x, const double* v, double c_third,
                               Workspace& ws) const;
  void drag_jacobian(const MatX& w, Eigen::Index cols, MatX& jac) const;
  // out (M + 6 square) = -W^T W for W's `count` rows of width face_rows_pad_.cols() (M + 6
  // padded to a multiple of 4) at `rows`, by the dispatched Gram kernel (gram: its scratch).
  // (The floating drag's J_d, W's columns being the rows; the penalty ground's J_pen.)
  void negative_gram(const double* rows, Eigen::Index count, MatX& gram, MatX& out) const;
  int solve_contacts(const ReducedConfig& cfg, const VecX& q, const MatX& a,
                     const Eigen::LLT<MatX>& a_llt, VecX& v, VecX& impulses, Workspace& ws,
                     StepInfo& info) const;
  // After a contact solve: appends to ws.contact_active (and contact_gap) every other surface
  // node c that the step's velocity takes below its bound by more than the contact tolerance,
  // from its height gap_of(c) and its normal velocity at the step's end, vn_end(c), asked
  // only where vn_at_least(c), a cheap lower bound on it, does not already clear the bound.
  // Returns how many it appended.
  template <class Gap, class LowerBound, class NormalVelocity>
  int add_missed_candidates(const ReducedConfig& cfg, Gap gap_of, LowerBound vn_at_least,
                            NormalVelocity vn_end, Workspace& ws, StepInfo& info) const {
    std::vector<int>& active = ws.contact_active;
    std::vector<char>& member = ws.contact_member;
    member.assign(num_surface_nodes(), 0);
    for (const int c : active) member[c] = 1;
    const double tol = cfg.contact_tolerance;
    int added = 0;
    for (int c = 0; c < num_surface_nodes(); ++c) {
      if (member[c]) continue;
      const double z = gap_of(c);
      const double bound = cfg.normal_velocity_bound(z) - tol;
      if (vn_at_least(c) >= bound || vn_end(c) >= bound) continue;
      active.push_back(c);
      ws.contact_gap.push_back(z);
      ++added;
    }
    info.active_rows = static_cast<int>(active.size());
    return added;
  }
  // When the rounds run out: the candidates add_missed_candidates appended after the first
  // `solved` were never in a solve; they are dropped, so that active_rows counts the
  // candidates the step's impulses were solved over (as the full space's mirror does).
  static void drop_unsolved_candidates(size_t solved, Workspace& ws, StepInfo& info) {
    ws.contact_active.resize(solved);
    ws.contact_gap.resize(solved);
    info.active_rows = static_cast<int>(solved);
  }
  // Penalty ground force f at (q, v), and, when jac is not null (the Newton matrix needs it;
  // the line search's residuals do not), its velocity Jacobian's symmetric part in *jac and
  // the friction's coupling to the normal force C (not symmetric): the reference solver's in
  // ws.j_pen_coupling, the fast solver's as the rows that penalty_coupling_times (C x) and
  // penalty_coupling_matrix (C) read, in ws's scratch (pen_*).
  void penalty_contacts(const ReducedConfig& cfg, const VecX& q, const VecX& v, VecX& f,
                        MatX* jac, Workspace& ws) const;
  // The fast solver's coupling C times x, and C itself, from the rows penalty_contacts_fast
  // left in ws: valid only after its call with jac on the same iterate.
  void penalty_coupling_times(const VecX& x, VecX& out, Workspace& ws) const;
  void penalty_coupling_matrix(Workspace& ws, MatX& out) const;
  void penalty_contacts_fast(const ReducedConfig& cfg, const VecX& q, const VecX& v, VecX& f,
                             MatX* jac, Workspace& ws) const;
  // Surface node c's penalty normal force at height z above the ground (negative: below it)
  // and normal velocity vz, and (out) the factor -d f / d vz of its normal row in the Jacobian
  // (k h + d past the damper's ramp).
  double penalty_normal_force(const ReducedConfig& cfg, size_t c, double z, double vz,
                              double& jacobian_factor) const;

  int num_nodes_ = 0;
  Eigen::Index basis_cols_ = 0;
  double total_mass_ = 0.0;
  int rest_contacts_ = 1;   // surface nodes on the lowest plane at rest (penalty sizing)
  static constexpr double kPenaltySink = 1e-3;  // m of sink per body weight (penalty default)
  // m of sink over which the penalty damper ramps in (a tenth of kPenaltySink). A damper on
  // from z = 0 made the force jump by d |v_z| where a node arrives, and Newton found no root
  // on up to 6 % of walking steps. 10 um already removed every such cap (benchmarks/PROFILE.md,
  // session 50); 0.1 mm keeps the change to the first tenth of the sink the stiffness is
  // sized for.
  static constexpr double kPenaltyDamperRamp = 1e-4;
  // Re-solves of a contact step after nodes outside its candidates were found driven below
  // the ground (solve_contacts); measured: one at most on the walkers' gaits.
  static constexpr int kMaxCandidateRounds = 3;
  Vec3 rest_com_;
  // Cubature over K elements (k = 1..K): G = [G_1; ...; G_K] stacked (9K x (M + 3)),
  // G_k = d vec(F_k) / d q_e, and wvol_[k] = w_k V_k, the element's cubature weight (the
  // paper's w_e) times its rest volume. Stacking turns the reduced force and stiffness into
  // matrix products instead of K small ones.
  RowMatX grad_;
  // The fast kernels' copy of G, padded with zero columns to a multiple of 4, so every row is
  // whole AVX2 packets (the quadruped's M + 3 = 23 would leave a scalar tail on each of the
  // 9K rows) for the kernels of dense_kernels.h (measured in benchmarks/PROFILE.md). The
  // reference kernel (elastic_reference) keeps grad_; K_r(rest), which both solvers use,
  // comes from this one.
  RowMatX grad_fast_;
  // G interleaved by elements (dense_kernels.h) for the force's one pass and the stiffness's
  // deformation gradients, and w_k V_k padded to its groups of four (0 on the padding).
  std::vector<double> grad_lanes_, wvol_lanes_;
  std::vector<double> wvol_;
  StableNeoHookean material_;
  // Surface: rows of B_r (3 x (M + 6)) and rest positions of each surface node.
  std::vector<int> surface_nodes_;
  RowMatX surface_rows_;   // (3 n_s) x (M + 6)
  RowMatX normal_rows_;    // n_s x (M + 6): the z rows alone, for the candidate search
  MatX normal_cols_;       // the same, column-major: near_ground's N q, N v (cols_times_pair)
  VecX normal_row_norms_;  // |N_c|: bounds a node's normal velocity change by |N_c| |dv|
  VecX surface_deform_norms_;  // |U_c| (Frobenius) of each surface node's deformation rows
  MatX surface_cols_;      // surface_rows_ column-major, for the fast drag (cols_times_pair)
  VecX surface_rest_;      // 3 n_s
  std::vector<std::array<int, 3>> faces_;  // indices into surface nodes
  RowMatX face_rows_;      // (3 n_f) x (M + 6): the mean of each face's three node rows
  RowMatX face_rows_pad_;  // the same with zero columns up to a multiple of 4 (drag_fast's)
  std::vector<std::ptrdiff_t> face_corners_;  // 3 per face: its nodes' offsets 3 c in x_s
  VecX node_mass_surface_; // lumped mass of each surface node
  MatX basis_;             // full B_r, for positions()
  std::vector<Tet> tets_;  // every tetrahedron, and 1 / (6 V) of each, for min_volume_ratio
  std::vector<double> inv_rest_det_;
  VecX rest_;
  // The floating frame's kinetic coefficients (floating_frame.h), and the rest nodes about the
  // centre of mass.
  FloatingCoefficients floating_;
  VecX rest_about_com_;
  MatX control_basis_;     // B_c, M x C
  MatX k_rest_;            // K_r at rest (cubature), for Rayleigh damping and A_0
  // The last A_0^-1 that inputs() formed, and the settings it was formed for: A_0 depends on
  // dt, damping_alpha and damping_beta alone (K_0 is fixed with the model, and B_c does not
  // enter it), so a Python step or rollout forms it again only when one of them has changed,
  // however the settings were written (a property, a whole config). Keyed by the values, not
  // invalidated by the setters: equal values form the same bits. The mutex makes inputs() safe
  // to call from several threads, as a const method should be.
  struct RestNewtonCache {
    bool formed = false;
    double dt = 0.0, damping_alpha = 0.0, damping_beta = 0.0;
    std::shared_ptr<const MatX> inverse;
  };
  mutable std::mutex rest_newton_mutex_;
  mutable RestNewtonCache rest_newton_cache_;
  // The workspaces lent and given back, for the next lend_workspace.
  mutable std::mutex workspace_mutex_;
  mutable std::vector<std::unique_ptr<Workspace>> idle_workspaces_;
};

}  // namespace softrom
