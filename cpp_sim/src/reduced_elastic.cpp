// Cubature elastic kernels: the reduced energy Psi(q_e) = sum_k w_k V_k psi(F_k), the force
// f_e = -dPsi/dq_e = -sum_k w_k V_k G_k^T vec P(F_k) and the stiffness
// K_r = sum_k w_k V_k G_k^T (dP/dF)(F_k) G_k, with vec F_k = vec I + G_k q_e, over the K
// cubature elements k with weights w_k (the paper's w_e) and rest volumes V_k (wvol_).
#include <algorithm>

#include <Eigen/Dense>

#include "dense_kernels.h"
#include "reduced_model.h"

namespace softrom {

// The reference kernel: per-element dynamic products, optional per-element PSD projection.
void ReducedModel::elastic_reference(const VecX& qe, bool project, double* energy, VecX* force,
                                     MatX* stiff) const {
  const Eigen::Index md = qe.size();
  const Eigen::Index nk = static_cast<Eigen::Index>(wvol_.size());
  VecX fall = grad_ * qe;
  VecX pall(force ? 9 * nk : 0);
  RowMatX hg(stiff ? 9 * nk : 0, md);
  double en = 0.0;
  for (Eigen::Index k = 0; k < nk; ++k) {
    double* fv = fall.data() + 9 * k;
    fv[0] += 1.0;
    fv[4] += 1.0;
    fv[8] += 1.0;
    const Eigen::Map<const Mat3> f(fv);
    const double w = wvol_[k];
    if (energy) en += w * material_.energy_density(f);
    if (force) {
      const Mat3 p = material_.pk1(f);
      Eigen::Map<Vec9>(pall.data() + 9 * k) = w * Eigen::Map<const Vec9>(p.data());
    }
    if (stiff) {
      Mat9 dp = material_.dpdf(f);
      if (project && !nearly_psd<9>(dp)) dp = project_psd<9>(dp);
      hg.middleRows(9 * k, 9).noalias() = (w * dp) * grad_.middleRows(9 * k, 9);
    }
  }
  if (energy) *energy = en;
  if (force) force->noalias() = -(grad_.transpose() * pall);
  if (stiff) {
    stiff->noalias() = grad_.transpose() * hg;
    // Symmetrise away round-off so the LDL^T sees an exactly symmetric matrix.
    *stiff = 0.5 * (*stiff + stiff->transpose()).eval();
  }
}

// G q_e into ws.f_minus_i (vec F_k - vec I for every element), from the interleaved G.
void ReducedModel::deformation_gradients_fast(const VecX& qe, Workspace& ws) const {
  const Eigen::Index nk = static_cast<Eigen::Index>(wvol_.size());
  ws.f_minus_i.resize(9 * nk);
  kernels::interleaved_deformation(grad_lanes_.data(), nk, qe.size(), qe.data(),
                                   ws.f_minus_i.data());
}

// Energy and force in one pass over the interleaved G (kernels::snh_force): each group of four
// elements' F, stresses and G^T P while its block of G is in L1.
double ReducedModel::elastic_energy_force(const VecX& qe, VecX& force, Workspace& ws) const {
  const Eigen::Index md = qe.size();
  const Eigen::Index groups = static_cast<Eigen::Index>(wvol_lanes_.size()) / 4;
  ws.force_lanes.resize(4 * md);
  force.resize(md);
  const double en =
      kernels::snh_force(grad_lanes_.data(), groups, md, qe.data(), wvol_lanes_.data(),
                         material_.mu, material_.lambda, ws.force_lanes.data(), force.data());
  force = -force;  // f_e = -G^T P
  return en;
}

// The stiffness as two products on the padded G (grad_fast_; the padding's rows and columns of
// the product are zero and dropped): H G, element by element, from F and its cofactor without
// forming H (kernels::snh_element_hg), and the lower triangle of G^T (H G)
// (kernels::gram_lower_add). They go a few elements at a time, so a group's 9 x mp blocks of
// H G are still in L1 when the Gram product reads them (the whole H G is ~0.25 MB on the
// quadruped); the sum is the same, bit for bit, as one Gram product.
void ReducedModel::elastic_stiffness_fast(const VecX& qe, MatX& stiff, Workspace& ws) const {
  constexpr Eigen::Index kGroup = 5;  // 45 rows: the Gram kernel's row chunk
  const Eigen::Index md = qe.size(), mp = grad_fast_.cols();
  const Eigen::Index nk = static_cast<Eigen::Index>(wvol_.size());
  deformation_gradients_fast(qe, ws);
  ws.hg.resize(9 * kGroup, mp);
  ws.k_pad.setZero(mp, mp);
  const double mu = material_.mu, lambda = material_.lambda;
  double coef[28];  // kernels::snh_element_hg's
  for (Eigen::Index k0 = 0; k0 < nk; k0 += kGroup) {
    const Eigen::Index k1 = std::min(k0 + kGroup, nk);
    for (Eigen::Index k = k0; k < k1; ++k) {
      Eigen::Map<Mat3> f(ws.f_minus_i.data() + 9 * k);
      // (F - I becomes F in place: the buffer is not read again before the next G q_e.)
      f.diagonal().array() += 1.0;
      const Mat3 cof = StableNeoHookean::cofactor(f);
      const double w = wvol_[k];
      const double w_s = w * (lambda * (f.col(0).dot(cof.col(0)) - 1.0) - mu);
      for (int i = 0; i < 9; ++i) {
        coef[i] = cof.data()[i];
        coef[9 + i] = (w * lambda) * cof.data()[i];
        coef[18 + i] = w_s * f.data()[i];
      }
      coef[27] = w * mu;
      kernels::snh_element_hg(coef, grad_fast_.data() + 9 * k * mp, mp,
                              ws.hg.data() + 9 * (k - k0) * mp);
    }
    kernels::gram_lower_add(grad_fast_.data() + 9 * k0 * mp, ws.hg.data(), 9 * (k1 - k0), mp,
                            ws.k_pad.data());
  }
  stiff.resize(md, md);
  stiff.triangularView<Eigen::Lower>() = ws.k_pad.topLeftCorner(md, md);
  stiff.triangularView<Eigen::StrictlyUpper>() = stiff.transpose();
}

double ReducedModel::elastic_energy(const VecX& qe) const {
  double e;
  elastic_reference(qe, false, &e, nullptr, nullptr);
  return e;
}

double ReducedModel::elastic_energy_fast(const VecX& qe) const {
  Workspace ws;
  VecX f;
  return elastic_energy_force(qe, f, ws);
}

VecX ReducedModel::elastic_forces(const VecX& qe) const {
  Workspace ws;
  VecX f;
  elastic_energy_force(qe, f, ws);
  return f;
}

MatX ReducedModel::elastic_stiffness(const VecX& qe, bool project) const {
  MatX k;
  if (project) {
    elastic_reference(qe, true, nullptr, nullptr, &k);
  } else {
    Workspace ws;
    elastic_stiffness_fast(qe, k, ws);
  }
  return k;
}

}  // namespace softrom
