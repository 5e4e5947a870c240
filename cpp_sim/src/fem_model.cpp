#include "fem_model.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "snh_eigensystem.h"

namespace softrom {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point& t0) {
  const Clock::time_point now = Clock::now();
  const double s = std::chrono::duration<double>(now - t0).count();
  t0 = now;
  return s;
}

}  // namespace

FEMModel::FEMModel(const VecX& rest_positions, std::vector<Tet> tets, double youngs_modulus,
                   double poisson_ratio, double density)
    : mesh_(rest_positions, std::move(tets)),
      material_(StableNeoHookean::from_young_poisson(youngs_modulus, poisson_ratio)),
      youngs_(youngs_modulus),
      poisson_(poisson_ratio),
      density_(density) {
  mass_ = mesh_.lumped_mass(density);
  const int n = mesh_.num_nodes;
  mass3_.resize(3 * n);
  for (int i = 0; i < n; ++i) mass3_.segment<3>(3 * i).setConstant(mass_[i]);

  // Sparsity: full 3x3 blocks for every pair of nodes sharing a tet, plus every diagonal so
  // that isolated nodes (and fixed DOFs) still have a pivot.
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(mesh_.tets.size() * 144 + 3 * n);
  for (const Tet& t : mesh_.tets)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b)
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 3; ++j) trip.emplace_back(3 * t[a] + i, 3 * t[b] + j, 1.0);
  for (int d = 0; d < 3 * n; ++d) trip.emplace_back(d, d, 1.0);
  pattern_.resize(3 * n, 3 * n);
  pattern_.setFromTriplets(trip.begin(), trip.end());
  pattern_.makeCompressed();

  auto slot = [&](int row, int col) {
    const int* begin = pattern_.innerIndexPtr() + pattern_.outerIndexPtr()[col];
    const int* end = pattern_.innerIndexPtr() + pattern_.outerIndexPtr()[col + 1];
    return static_cast<int>(std::lower_bound(begin, end, row) - pattern_.innerIndexPtr());
  };
  slots_.resize(mesh_.tets.size() * 144);
  for (size_t e = 0; e < mesh_.tets.size(); ++e) {
    const Tet& t = mesh_.tets[e];
    for (int a = 0; a < 4; ++a)
      for (int i = 0; i < 3; ++i)
        for (int b = 0; b < 4; ++b)
          for (int j = 0; j < 3; ++j)
            slots_[e * 144 + (3 * a + i) * 12 + 3 * b + j] = slot(3 * t[a] + i, 3 * t[b] + j);
  }
  diag_slots_.resize(3 * n);
  for (int d = 0; d < 3 * n; ++d) diag_slots_[d] = slot(d, d);
}

FEMModel::~FEMModel() = default;

double FEMModel::energy(const VecX& x) const {
  double e = 0.0;
  for (int t = 0; t < mesh_.num_tets(); ++t)
    e += mesh_.volume[t] * material_.energy_density(mesh_.deformation_gradient(t, x));
  return e;
}

VecX FEMModel::forces(const VecX& x) const {
  VecX f = VecX::Zero(x.size());
  for (int t = 0; t < mesh_.num_tets(); ++t) {
    const Mat3 p = material_.pk1(mesh_.deformation_gradient(t, x));
    // f_a = -V P D_m^{-T} e_a for a = 1..3, f_0 = -(f_1 + f_2 + f_3).
    const Mat3 h = -mesh_.volume[t] * p * mesh_.dm_inv[t].transpose();
    const Tet& tet = mesh_.tets[t];
    for (int k = 0; k < 3; ++k) f.segment<3>(3 * tet[k + 1]) += h.col(k);
    f.segment<3>(3 * tet[0]) -= h.rowwise().sum();
  }
  return f;
}

void FEMModel::assemble(const VecX& x, bool project, SpMat& k) const {
  k = pattern_;
  std::fill(k.valuePtr(), k.valuePtr() + k.nonZeros(), 0.0);
  double* val = k.valuePtr();
  for (int t = 0; t < mesh_.num_tets(); ++t) {
    const Mat3 f = mesh_.deformation_gradient(t, x);
    Mat9 dp;
    if (project && solver_kind_ != FEMSolver::kReference) {
      dp = project_stable_neo_hookean(material_, f).matrix();
    } else {
      dp = material_.dpdf(f);
      // Most elements are stable; a 9x9 Cholesky is far cheaper than the eigen decomposition.
      if (project && !nearly_psd<9>(dp)) dp = project_psd<9>(dp);
    }
    const Eigen::Matrix<double, 9, 12> d = dfdx(mesh_.dm_inv[t]);
    const Eigen::Matrix<double, 12, 12> ke = mesh_.volume[t] * d.transpose() * dp * d;
    const int* s = &slots_[static_cast<size_t>(t) * 144];
    for (int r = 0; r < 12; ++r)
      for (int c = 0; c < 12; ++c) val[s[r * 12 + c]] += ke(r, c);
  }
}

SpMat FEMModel::stiffness(const VecX& x, bool project) const {
  SpMat k;
  assemble(x, project, k);
  return k;
}

double FEMModel::incremental_potential(const VecX& x, const VecX& x_tilde, const VecX& x_n,
                                       const SpMat& damping_k, double dt) const {
  const VecX dxt = x - x_tilde;
  const VecX dxn = x - x_n;
  double phi = 0.5 / (dt * dt) * dxt.dot(mass3_.cwiseProduct(dxt)) + energy(x);
  for (int i = 0; i < mesh_.num_nodes; ++i)
    phi -= mass_[i] * gravity.dot(x.segment<3>(3 * i));
  phi += 0.5 / dt *
         (damping_alpha * dxn.dot(mass3_.cwiseProduct(dxn)) +
          damping_beta * dxn.dot(damping_k * dxn));
  return phi;
}

void FEMModel::step(const VecX& x_n, const VecX& v_n, double dt, const std::vector<char>& fixed,
                    VecX& x_out, VecX& v_out) {
  if (solver_kind_ == FEMSolver::kReference)
    step_reference(x_n, v_n, dt, fixed, x_out, v_out);
  else
    step_fast(x_n, v_n, dt, fixed, x_out, v_out);
}

void FEMModel::step_reference(const VecX& x_n, const VecX& v_n, double dt,
                              const std::vector<char>& fixed, VecX& x_out, VecX& v_out) {
  const int ndof = 3 * mesh_.num_nodes;
  const bool any_fixed = std::any_of(fixed.begin(), fixed.end(), [](char c) { return c != 0; });
  VecX x_tilde = x_n + dt * v_n;
  VecX x = x_n;
  VecX mg(ndof);
  for (int i = 0; i < mesh_.num_nodes; ++i) mg.segment<3>(3 * i) = mass_[i] * gravity;

  SpMat k0, k, h;
  stats_ = StepStats{};
  for (int it = 0; it < max_newton_iterations; ++it) {
    Clock::time_point t0 = Clock::now();
    if (it == 0) {
      assemble(x, true, k0);
      k = k0;
    } else {
      assemble(x, true, k);
    }
    stats_.assemble_s += seconds_since(t0);
    // Gradient of the incremental potential (its negative is the residual force).
    const VecX dxn = x - x_n;
    VecX grad = mass3_.cwiseProduct(x - x_tilde) / (dt * dt) - forces(x) - mg +
                (damping_alpha * mass3_.cwiseProduct(dxn) + damping_beta * (k0 * dxn)) / dt;
    stats_.gradient_s += seconds_since(t0);
    // Hessian M/dt^2 + K(x) + (alpha M + beta K0)/dt, built on the shared pattern.
    h = k;
    double* hv = h.valuePtr();
    const double* k0v = k0.valuePtr();
    const double kb = damping_beta / dt;
    for (Eigen::Index s = 0; s < h.nonZeros(); ++s) hv[s] += kb * k0v[s];
    for (int d = 0; d < ndof; ++d)
      hv[diag_slots_[d]] += mass3_[d] * (1.0 / (dt * dt) + damping_alpha / dt);
    if (any_fixed) {
      for (int col = 0; col < ndof; ++col)
        for (int s = h.outerIndexPtr()[col]; s < h.outerIndexPtr()[col + 1]; ++s) {
          const int row = h.innerIndexPtr()[s];
          if (fixed[row / 3] || fixed[col / 3]) hv[s] = (row == col) ? 1.0 : 0.0;
        }
      for (int d = 0; d < ndof; ++d)
        if (fixed[d / 3]) grad[d] = 0.0;
    }
    stats_.assemble_s += seconds_since(t0);
    if (!analysed_) {
      solver_.analyzePattern(h);
      analysed_ = true;
    }
    solver_.factorize(h);
    if (solver_.info() != Eigen::Success)
      throw std::runtime_error("implicit Euler: sparse factorisation failed");
    ++stats_.factorizations;
    stats_.factorize_s += seconds_since(t0);
    const VecX dx = solver_.solve(-grad);
    stats_.solve_s += seconds_since(t0);
    const double step_norm = dx.cwiseAbs().maxCoeff() / dt;
    stats_.iterations = it + 1;
    stats_.step_norm = step_norm;
    if (!std::isfinite(step_norm))
      throw std::runtime_error("implicit Euler: Newton step is not finite (simulation diverged)");
    if (step_norm < newton_tolerance) {
      x += dx;
      stats_.converged = true;
      break;
    }
    // Backtracking (Armijo) line search on the incremental potential.
    const double phi0 = incremental_potential(x, x_tilde, x_n, k0, dt);
    ++stats_.energy_evaluations;
    const double slope = grad.dot(dx);
    double alpha = 1.0;
    VecX trial = x + dx;
    while (alpha > 1e-6) {
      const double phi = incremental_potential(trial, x_tilde, x_n, k0, dt);
      ++stats_.energy_evaluations;
      if (std::isfinite(phi) && phi <= phi0 + 1e-4 * alpha * slope) break;
      alpha *= 0.5;
      trial = x + alpha * dx;
    }
    x = trial;
    stats_.line_search_s += seconds_since(t0);
  }
  x_out = x;
  v_out = (x - x_n) / dt;
}

void FEMModel::assemble_projected_upper(const VecX& x, std::vector<double>& k) const {
  k.assign(static_cast<size_t>(system_->nonzeros()), 0.0);
  for (int t = 0; t < mesh_.num_tets(); ++t) {
    const ProjectedHessian h =
        project_stable_neo_hookean(material_, mesh_.deformation_gradient(t, x));
    // K_e = V B^T H B = sum_i (sqrt(V l_i) B^T q_i)(...)^T, and B^T vec(Q) puts column a of
    // Q D_m^{-T} on node a + 1 and minus their sum on node 0.
    Eigen::Matrix<double, 12, 9> b = Eigen::Matrix<double, 12, 9>::Zero();
    const Mat3 dm_inv_t = mesh_.dm_inv[t].transpose();
    for (int i = 0; i < h.count; ++i) {
      const Mat3 g = std::sqrt(mesh_.volume[t] * h.eigenvalue[i]) * h.q[i] * dm_inv_t;
      b.block<3, 1>(0, i) = -g.rowwise().sum();
      b.block<9, 1>(3, i) = Eigen::Map<const Vec9>(g.data());
    }
    // A fixed-size product (vectorised, unrolled) beats 78 dots of run-time length.
    Eigen::Matrix<double, 12, 12> ke;
    ke.noalias() = b * b.transpose();
    const int* s = system_->element_slots(t);
    for (int p = 0; p < 12; ++p)
      for (int q = p; q < 12; ++q) k[*s++] += ke(p, q);
  }
}

void FEMModel::assemble_exact_upper(const VecX& x, std::vector<double>& k) const {
  k.assign(static_cast<size_t>(system_->nonzeros()), 0.0);
  for (int t = 0; t < mesh_.num_tets(); ++t) {
    const Mat9 dp = material_.dpdf(mesh_.deformation_gradient(t, x));
    const Eigen::Matrix<double, 9, 12> d = dfdx(mesh_.dm_inv[t]);
    Eigen::Matrix<double, 12, 12> ke;
    ke.noalias() = mesh_.volume[t] * d.transpose() * dp * d;
    const int* s = system_->element_slots(t);
    for (int p = 0; p < 12; ++p)
      for (int q = p; q < 12; ++q) k[*s++] += ke(p, q);
  }
}

void FEMModel::step_fast(const VecX& x_n, const VecX& v_n, double dt,
                         const std::vector<char>& fixed, VecX& x_out, VecX& v_out) {
  if (!system_) system_ = std::make_unique<SpdSystem>(mesh_);
  SpdSystem& sys = *system_;
  const Factorization kind = solver_kind_ == FEMSolver::kSimplicialLDLT
                                 ? Factorization::kSimplicialLDLT
                             : solver_kind_ == FEMSolver::kSupernodalLLT
                                 ? Factorization::kSupernodalLLT
                                 : Factorization::kSimplicialLLT;
  const int ndof = 3 * mesh_.num_nodes;
  const bool any_fixed = std::any_of(fixed.begin(), fixed.end(), [](char c) { return c != 0; });
  const double inv_dt2 = 1.0 / (dt * dt);
  const double mass_coef = inv_dt2 + damping_alpha / dt;  // H >= mass_coef M
  const double kb = damping_beta / dt;
  const VecX x_tilde = x_n + dt * v_n;
  VecX mg(ndof);
  for (int i = 0; i < mesh_.num_nodes; ++i) mg.segment<3>(3 * i) = mass_[i] * gravity;
  double min_free_mass = std::numeric_limits<double>::infinity();
  for (int i = 0; i < mesh_.num_nodes; ++i)
    if (!any_fixed || !fixed[i]) min_free_mass = std::min(min_free_mass, mass_[i]);

  // Incremental potential at x; k0_dxn = K(x_n) (x - x_n) comes with it.
  VecX k0_dxn(ndof);
  auto potential = [&](const VecX& x) {
    const VecX dxt = x - x_tilde;
    const VecX dxn = x - x_n;
    sys.multiply(k0_, dxn, k0_dxn);
    ++stats_.energy_evaluations;
    const double damping = damping_alpha * dxn.dot(mass3_.cwiseProduct(dxn)) +
                           damping_beta * dxn.dot(k0_dxn);
    return 0.5 * inv_dt2 * dxt.dot(mass3_.cwiseProduct(dxt)) + energy(x) - mg.dot(x) +
           0.5 / dt * damping;
  };

  VecX x = x_n, grad(ndof), dx(ndof);
  double phi = 0.0;
  bool phi_known = false;  // phi holds the incremental potential at x
  // Newton on the PSD-projected K converges only linearly where elements are compressed far
  // (projection clamps the directions that matter there): hundreds of iterations on a stiff
  // squashed block, each stopping test passed while still 5-57x the tolerance from the
  // solution. Once an iteration fails to cut the step tenfold, later ones use the exact K(x)
  // wherever the Newton matrix with it factors (positive definite, so dx still descends),
  // and return to the projected one where it does not. Steps that converge fast, as every
  // step of the benchmarks does, never switch and are unchanged.
  bool exact = false;
  bool last_projected = true;  // the latest factorisation's H >= mass_coef M (see below)
  double previous_norm = std::numeric_limits<double>::infinity();
  stats_ = StepStats{};
  Clock::time_point t0 = Clock::now();
  for (int it = 0; it < max_newton_iterations; ++it) {
    stats_.iterations = it + 1;
    // Gradient of the incremental potential (its negative is the residual force).
    const VecX dxn = x - x_n;
    if (it == 0)
      k0_dxn.setZero();
    else if (!phi_known)  // otherwise the line search's last potential left it at this x
      sys.multiply(k0_, dxn, k0_dxn);
    grad = inv_dt2 * mass3_.cwiseProduct(x - x_tilde) - forces(x) - mg +
           (damping_alpha * mass3_.cwiseProduct(dxn) + damping_beta * k0_dxn) / dt;
    if (any_fixed)
      for (int d = 0; d < ndof; ++d)
        if (fixed[d / 3]) grad[d] = 0.0;
    stats_.gradient_s += seconds_since(t0);

    // The Newton matrix H satisfies H >= mass_coef M (K(x) and K(x_n) are projected PSD), so
    // the Newton step dx = -H^{-1} grad has max |dx_i| <= |M^{-1/2} grad| / (mass_coef
    // sqrt(min m_i)). Below the tolerance that proves this iteration converges; the update is
    // then taken with the previous iteration's factorisation, which the same bound covers,
    // and the factorisation that would only have confirmed convergence is skipped.
    if (it > 0 && last_projected) {
      const double bound = std::sqrt(grad.cwiseAbs2().cwiseQuotient(mass3_).sum()) /
                           (mass_coef * std::sqrt(min_free_mass)) / dt;
      if (bound < newton_tolerance) {
        sys.solve(-grad, dx);
        stats_.solve_s += seconds_since(t0);
        stats_.step_norm = dx.cwiseAbs().maxCoeff() / dt;
        stats_.converged = true;
        x += dx;
        break;
      }
    }

    // Newton matrix M/dt^2 + K(x) + (alpha M + beta K(x_n))/dt on the pre-permuted pattern
    // (the damping's K(x_n) always projected: D must be PSD to dissipate).
    auto factorize_with = [&](const std::vector<double>& k) {
      double* hv = sys.values();
      for (size_t s = 0; s < k.size(); ++s) hv[s] = k[s] + kb * k0_[s];
      for (int d = 0; d < ndof; ++d) hv[sys.diagonal_slot(d)] += mass3_[d] * mass_coef;
      if (any_fixed) sys.clamp(fixed);
      stats_.assemble_s += seconds_since(t0);
      ++stats_.factorizations;
      sys.factorize(kind);
      stats_.factorize_s += seconds_since(t0);
    };
    bool factored = false;
    if (exact) {
      assemble_exact_upper(x, k_);
      try {
        factorize_with(k_);
        factored = true;
        last_projected = false;
      } catch (const std::runtime_error&) {  // indefinite here: the projected matrix instead
        stats_.factorize_s += seconds_since(t0);
      }
    }
    if (!factored) {
      if (it == 0) {
        assemble_projected_upper(x, k0_);
      } else {
        assemble_projected_upper(x, k_);
      }
      factorize_with(it == 0 ? k0_ : k_);
      last_projected = true;
    }
    sys.solve(-grad, dx);
    stats_.solve_s += seconds_since(t0);

    const double step_norm = dx.cwiseAbs().maxCoeff() / dt;
    stats_.step_norm = step_norm;
    if (!std::isfinite(step_norm))
      throw std::runtime_error("implicit Euler: Newton step is not finite (simulation diverged)");
    if (step_norm < newton_tolerance) {
      x += dx;
      stats_.converged = true;
      break;
    }
    if (step_norm > 0.1 * previous_norm) exact = true;
    previous_norm = step_norm;
    // Backtracking (Armijo) line search on the incremental potential; the potential at the
    // accepted point is the next iteration's starting value.
    const double phi0 = phi_known ? phi : potential(x);
    const double slope = grad.dot(dx);
    double alpha = 1.0;
    VecX trial = x + dx;
    phi_known = false;
    while (alpha > 1e-6) {
      phi = potential(trial);
      if (std::isfinite(phi) && phi <= phi0 + 1e-4 * alpha * slope) {
        phi_known = true;
        break;
      }
      alpha *= 0.5;
      trial = x + alpha * dx;
    }
    x = trial;
    stats_.line_search_s += seconds_since(t0);
  }
  x_out = x;
  v_out = (x - x_n) / dt;
}

}  // namespace softrom
