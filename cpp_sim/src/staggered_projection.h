// Staggered projection (Kaufman, Sueda, James & Pai 2008) in reduced coordinates: the ground
// contact solve of a step (staggered_projection.cpp). ReducedModel::solve_contacts picks the
// step's candidate nodes and hands them to the worker's StaggeredProjection, which keeps its
// buffers from step to step (scratch.h), so a step allocates nothing once the worker has seen
// its largest sizes.
#pragma once

#include <Eigen/Dense>
#include <vector>

#include "nnls.h"
#include "reduced_model.h"
#include "scratch.h"
#include "stagger_acceleration.h"

namespace softrom {

class StaggeredProjection {
 public:
  // Projects the contact-free velocity v (in: v*, out: the post-contact velocity) onto the
  // contact conditions of the candidates `active` (surface node ids; `gap`: their heights
  // above the ground) in the metric A = a, with a_llt its Cholesky factor. surface_rows is
  // the model's (3 n_s) x (M + 6) map from reduced to surface-node velocities. `impulses` (3
  // per surface node: two tangential, one normal) warm-starts the solve by node id and
  // receives its impulses. `drift` (optional, one per candidate): the part of each
  // candidate's height change over the step that its velocity row does not predict (the
  // floating frame's rotation at second order in h omega); the bound on its normal velocity
  // moves by -drift / h. Returns the number of staggers; info gets the counts and flags.
  int solve(const ReducedConfig& cfg, const RowMatX& surface_rows, const std::vector<int>& active,
            const std::vector<double>& gap, const MatX& a, const Eigen::LLT<MatX>& a_llt,
            VecX& v, VecX& impulses, NnlsWorkspace& nnls, StepInfo& info,
            const std::vector<double>* drift = nullptr);
  // The last solve's problem again, from v = v* and the warm start `impulses`, with new
  // bounds (gap, drift) on the same candidates: its rows, metric, E, L^-1 and pool are kept.
  int resolve(const std::vector<int>& active, const std::vector<double>& gap,
              const std::vector<double>* drift, VecX& v, VecX& impulses, StepInfo& info);

 private:
  // One step's set-up, kept by resolve: the candidates' rows, E and L^-1, the empty pool.
  void set_up(const RowMatX& surface_rows, const std::vector<int>& active);
  // One solve's start: the bounds, the warm start and the first stagger's reference.
  void start(const std::vector<int>& active, const std::vector<double>& gap,
             const std::vector<double>* drift, const VecX& impulses);
  // The stagger loop from start() to the impulses; returns the staggers.
  int run(const std::vector<int>& active, const std::vector<double>& gap,
          const std::vector<double>* drift, VecX& impulses);
  // out = A x for a column-major A (J_n, Y): the fast solver's kernel, Eigen's in the reference.
  template <class Matrix, class Vector>
  void times(const Matrix& a, const Vector& x, ScratchVec& out) const;
  void upper_solve(ScratchVec& x);
  template <class Vector>
  Eigen::Vector2d tangent(int i, const Vector& x) const;
  const ScratchVec& velocity_after(const ScratchMat& j, const ScratchVec& lam);
  // v* + A^-1 J^T lambda for the warm start's impulses (v* when they are zero), in response_.
  const ScratchVec& warm_start_velocity();
  template <class Vector>
  const ScratchVec& loaded_tangents(const Vector& x);
  void normal_solve(const ScratchVec& v_prime);
  bool normal_on_loaded_set();
  void enter_pool(const std::vector<int>& set);
  void build_rows(const std::vector<int>& set);
  void friction_half(bool on_set);
  double stagger_change();
  double normal_violation();
  bool held_set_newton();
  void trace_start();
  void trace_normal(bool on_set);

  // The step's inputs and settings (solve's arguments).
  const ReducedConfig* cfg_ = nullptr;
  const MatX* a_ = nullptr;
  const Eigen::LLT<MatX>* a_llt_ = nullptr;
  VecX* v_ = nullptr;
  NnlsWorkspace* nnls_ = nullptr;
  StepInfo* info_ = nullptr;
  Eigen::Index m_ = 0;  // M + 6 reduced velocities
  int k_ = 0;           // candidates
  bool fast_ = false;   // the fast solver's variants (the reference keeps the original arithmetic)
  NnlsSolve how_ = NnlsSolve::Qr;
  double mu_ = 0.0, tol_ = 0.0, eps_ = 0.0;
  int pool_size_ = 0;

  // The step's buffers; solve() and the methods above say what each holds.
  std::vector<int> loaded_, jt_l_set_, pool_slot_;
  std::vector<char> traced_;  // with config.profile: loaded at the last traced stagger
  std::vector<Eigen::Index> slots_;
  ScratchVec old_, b_, lam_n_, lam_t_, v_free_, solve_tmp_, response_, x_ldp_, lam_ldp_, row_gap_,
      vc_prev_, vc_, weight_, v_prev_, dv_stagger_, v_second_, ut_l_, rhs_l_, lam_w_, v_on_,
      pool_c_, tangent_row_, lam_held_, b_held_;
  ScratchMat jn_, jt_, g_, gt_, et_rows_, l_inv_, l_inv_t_, hess_, wjt_, jt_l_, dual_sys_, pool_y_,
      pool_gram_, gram_;
  ScratchRowMat y_rows_;
  LoadedRows rows_;
  StaggerExtrapolation extrapolation_;
  HeldSetNewton held_newton_;
};

}  // namespace softrom
