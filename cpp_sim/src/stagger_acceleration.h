// The fast solver's ways of taking fewer and cheaper staggers (staggered_projection.cpp): an
// Aitken jump along a creeping stagger sequence, the loaded set's rows in the step's metric,
// and Newton's method on staggering's fixed point over a held loaded set.
#pragma once

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <vector>

#include "scratch.h"
#include "small_cholesky.h"

namespace softrom {

// Vector Aitken extrapolation of the stagger map (fast solver only).
//
// Near its fixed point staggering converges linearly, and on the walkers slowly: traced on the
// quadruped, the last staggers of a long step are one sliding foot node whose normal impulse
// creeps up by the same small amount every stagger (its friction shifts load onto it, which
// raises its friction), a contraction rate of 0.9-0.99. When the loaded set has held for
// three staggers and two successive changes of the impulses d_k, d_(k-1) point the same way
// (cosine > 0.9), the sequence is taken as geometric with ratio r = d_k.d_(k-1) / |d_(k-1)|^2
// and, if it is slow (0.5 <= r < 1), the friction impulses jump towards its limit,
// lambda_t += min(r / (1 - r), 10) d_k,t (the next normal solve answers the jump; the friction
// half-step after it puts lambda_t back inside the Coulomb discs, so they are not projected
// here: clipping the jump to the current discs undid it for the sliding nodes it is for). The
// fixed point is staggering's own: a step is declared converged only on two plain staggers
// after the last jump, by the same test, and no jump is made in the last staggers before the
// cap. A step makes at most kMaxJumps jumps: unlimited, the jumps can drive staggering round
// a cycle that never settles (a jump shifts load between the nodes of a foot, staggering
// creeps back, the next jump shifts it again). On four open-loop tripod gaits with the cap
// raised to 400, 11.4 % of the steps never converged; with at most 5 jumps 1.1 %, with none
// 0.6 %. Measured in benchmarks/PROFILE.md (2026-12-03, Aitken entry and the entry on its
// jump limit).
class StaggerExtrapolation {
 public:
  // A step's start, from its first impulses.
  void reset(const ScratchVec& lam_n, const ScratchVec& lam_t) {
    k_ = lam_n.size();
    last_.resize(3 * k_);
    d_.resize(3 * k_);
    d_prev_.resize(3 * k_);
    last_ << lam_n, lam_t;
    loaded_.clear();
    held_ = 0;
    jumps_ = 0;
    have_d_ = false;
  }

  // The impulses at the end of a stagger; returns the factor f of the jump
  // lambda_t += f (lambda_t - lambda_t,prev), 0 for none.
  double observe(const ScratchVec& lam_n, const ScratchVec& lam_t, const std::vector<int>& loaded) {
    if (loaded == loaded_) {
      ++held_;
    } else {
      held_ = 0;
      loaded_ = loaded;
    }
    d_prev_.swap(d_);
    d_.head(k_) = lam_n - last_.head(k_);
    d_.tail(2 * k_) = lam_t - last_.tail(2 * k_);
    last_.head(k_) = lam_n;
    last_.tail(2 * k_) = lam_t;
    const bool have_pair = have_d_;
    have_d_ = true;
    if (!have_pair || held_ < kHold || jumps_ >= kMaxJumps) return 0.0;
    const double dd = d_prev_.squaredNorm(), cross = d_.dot(d_prev_);
    if (!(dd > 0.0) || !(cross > 0.0)) return 0.0;
    const double r = cross / dd;
    if (r >= 1.0 || r < kMinRatio || cross < kMinCosine * std::sqrt(dd * d_.squaredNorm()))
      return 0.0;
    return std::min(r / (1.0 - r), kMaxFactor);
  }

  // After a jump: lambda_t moved by f d_t, and the history starts again.
  void jumped(const ScratchVec& lam_t) {
    ++jumps_;
    last_.tail(2 * k_) = lam_t;
    have_d_ = false;
    held_ = 0;
    loaded_.clear();
  }

  auto friction_change() const { return d_.tail(2 * k_); }

 private:
  static constexpr int kHold = 2;  // the loaded set unchanged over the last two staggers
  static constexpr double kMinCosine = 0.9;
  static constexpr double kMinRatio = 0.5;  // faster sequences converge without help
  static constexpr double kMaxFactor = 10.0;
  static constexpr int kMaxJumps = 5;  // per step (the plateau of 4-6 measured on the tripod)
  Eigen::Index k_ = 0;
  ScratchVec last_, d_, d_prev_;  // (lambda_n, lambda_t): the last impulses and their changes
  std::vector<int> loaded_;
  int held_ = 0, jumps_ = 0;
  bool have_d_ = false;
};

// The loaded nodes' rows in the metric of the step (fast solver only), for the staggers in
// which the loaded set W holds (85-90 % of the staggers after the first on the quadruped,
// tripod and beam). On such a stagger both halves are small dense problems over W's 3 n
// impulses, and the velocity is formed once from them: v = v_free + L^-T Y lambda_W with
//   Y = L^-1 [J_n,W^T  J_t,W^T]   ((M + 6) x 3 n; the normal columns are columns of E^T),
//   D = Y^T Y = J_W A^-1 J_W^T    (the Delassus operator on W's rows),   c = J_W v_free.
// Such a stagger skips NNLS over every candidate and four of the six (M + 6) triangular
// solves, and factors nothing but the friction half's 2 n x 2 n system. callgrind_step.py (100
// random steps), instructions per stagger: quadruped 120 k -> 93 k, tripod 119 k -> 84 k, beam
// 99 k -> 77 k (benchmarks/PROFILE.md, session 12).
struct LoadedRows {
  std::vector<int> set;       // the loaded candidates, in the order of Y's columns
  std::vector<char> member;   // per candidate: in the set
  ScratchMat y, d;
  ScratchVec c;
  ScratchMat d_nn;            // the Cholesky factor of D's normal block, once per set
  bool normal_ok = false;     // W's normal rows independent (D_nn positive definite)

  // A step's start (k candidates): no set.
  void reset(int k) {
    set.clear();
    member.assign(k, 0);
    normal_ok = false;
  }
};

// Newton's method on staggering's fixed point over a held loaded set W of n nodes (fast solver
// only), taken where the Aitken jump above would be: the set has held and the staggers creep.
// With the normal half exact on W (LoadedRows), the normal impulses and the loaded nodes'
// tangential velocities are affine in W's friction impulses lambda (2 n):
//   lambda_n = a0 + N lambda,   a0 = D_nn^-1 (b_W - c_n),   N = -D_nn^-1 D_nt,
//   u = u0 + T lambda,          u0 = c_t + D_tn a0,          T = D_tt + D_tn N,
// and the fixed point of the smoothed law lambda_l = -r_l u_l / s_l (r = mu lambda_n,
// s_l = sqrt(|u_l|^2 + eps^2)) is the root of F_l = r_l u_l + s_l lambda_l. Newton on the
// law in that form, with s_l an unknown (F2_l = s_l^2 - |u_l|^2 - eps^2) eliminated from the
// step (ds_l = (-F2_l + 2 u_l^T T_l dlambda) / (2 s_l)), solves
//   [(r_l I + lambda_l u_l^T / s_l) T_l + mu u_l N_l + s_l E_l] dlambda
//       = -F_l + lambda_l F2_l / (2 s_l)
// (T_l, N_l: node l's rows; E_l picks lambda_l), whose F2 term is zero here: s is reset to
// sqrt(|u|^2 + eps^2) after every step, so F2 = 0 at every iterate. Unlike Newton on
// lambda_l + r_l u_l / s_l, whose derivative mu lambda_n / eps at a sticking node confines its
// steps to ~eps (measured: it hovered there, benchmarks/PROFILE.md, the coupled Newton entry
// of 2026-12-03), this primal-dual form keeps lambda free of the law until the root, so a node
// crossing the stick-slip boundary costs an iteration or two. A try fails, and staggering goes
// on as before, when a step would take a node's load to zero or below (the answer needs
// another set: staggering's normal half finds it) or after kMaxIterations. The answer is
// staggering's own fixed point: the stagger after it must reproduce its velocity to the
// contact tolerance before the step ends (benchmarks/PROFILE.md, session 22).
class HeldSetNewton {
 public:
  // lam: W's friction impulses, node by node in the set's order (in: staggering's last; out:
  // the root). d, c: W's Delassus matrix and free contact velocities (LoadedRows), d_nn_factor
  // D_nn's Cholesky factor, b_w W's normal bounds.
  bool solve(const ScratchMat& d, const ScratchVec& c, const ScratchMat& d_nn_factor,
             const ScratchVec& b_w, double mu, double eps, double tol, ScratchVec& lam) {
    const Eigen::Index n = b_w.size(), n2 = 2 * n;
    a0_ = b_w - c.head(n);
    small::cholesky_upper_solve(d_nn_factor.data(), n, n, a0_.data());
    nm_ = -d.block(0, n, n, n2);
    for (Eigen::Index j = 0; j < n2; ++j)
      small::cholesky_upper_solve(d_nn_factor.data(), n, n, nm_.col(j).data());
    t_ = d.bottomRightCorner(n2, n2);
    t_.noalias() += d.block(n, 0, n2, n) * nm_;
    u_ = c.tail(n2);
    u_.noalias() += d.block(n, 0, n2, n) * a0_;
    u_.noalias() += t_ * lam;
    r_ = a0_;
    r_.noalias() += nm_ * lam;
    r_ *= mu;
    s_.resize(n);
    for (Eigen::Index l = 0; l < n; ++l)
      s_[l] = std::sqrt(u_.segment<2>(2 * l).squaredNorm() + eps * eps);
    jac_.resize(n2, n2);
    step_.resize(n2);
    for (int it = 0; it < kMaxIterations; ++it) {
      iterations_ = it;
      if (!(r_.array() > 0.0).all()) return fail('r');
      for (Eigen::Index l = 0; l < n; ++l) {
        const double u0 = u_[2 * l], u1 = u_[2 * l + 1], l0 = lam[2 * l], l1 = lam[2 * l + 1];
        step_[2 * l] = -(r_[l] * u0 + s_[l] * l0);
        step_[2 * l + 1] = -(r_[l] * u1 + s_[l] * l1);
        const double is = 1.0 / s_[l];
        const double p00 = r_[l] + l0 * u0 * is, p01 = l0 * u1 * is;
        const double p10 = l1 * u0 * is, p11 = r_[l] + l1 * u1 * is;
        const double m0 = mu * u0, m1 = mu * u1;
        for (Eigen::Index j = 0; j < n2; ++j) {
          const double t0 = t_(2 * l, j), t1 = t_(2 * l + 1, j), nj = nm_(l, j);
          jac_(2 * l, j) = p00 * t0 + p01 * t1 + m0 * nj;
          jac_(2 * l + 1, j) = p10 * t0 + p11 * t1 + m1 * nj;
        }
        jac_(2 * l, 2 * l) += s_[l];
        jac_(2 * l + 1, 2 * l + 1) += s_[l];
      }
      if (!small::lu_solve(jac_.data(), n2, step_.data()) || !step_.allFinite())
        return fail('s');
      du_.noalias() = t_ * step_;
      dr_.noalias() = nm_ * step_;
      dr_ *= mu;
      for (Eigen::Index l = 0; l < n; ++l)
        if (r_[l] + dr_[l] <= 0.0) return fail('l');  // a node leaves W
      lam += step_;
      u_ += du_;
      r_ += dr_;
      for (Eigen::Index l = 0; l < n; ++l)
        s_[l] = std::sqrt(u_.segment<2>(2 * l).squaredNorm() + eps * eps);
      // (Quadratic near the root: the next stagger's change is then far below tol.)
      if (du_.cwiseAbs().maxCoeff() < 0.1 * tol) {
        iterations_ = it + 1;
        failure_ = 0;
        return true;
      }
    }
    iterations_ = kMaxIterations;
    return fail('c');
  }

  // The last solve's Newton steps taken, and why it failed ('l': a node would leave W, 'r': a
  // load was not positive, 's': a singular step, 'c': the iteration cap; 0 after a root), for
  // the stagger trace.
  int iterations() const { return iterations_; }
  char failure() const { return failure_; }

  // The normal impulses lambda_n = a0 + N lambda of the last solve's set, into out (n).
  template <class Out>
  void normal_impulses(const ScratchVec& lam, Out&& out) const {
    out = a0_;
    out.noalias() += nm_ * lam;
  }

 private:
  // Measured on the walkers' tries (session 22): roots are reached in 2-8 iterations, most in 3-5.
  static constexpr int kMaxIterations = 8;
  bool fail(char why) {
    failure_ = why;
    return false;
  }
  int iterations_ = 0;
  char failure_ = 0;
  ScratchMat nm_, t_, jac_;
  ScratchVec a0_, u_, r_, s_, step_, du_, dr_;
};

}  // namespace softrom
