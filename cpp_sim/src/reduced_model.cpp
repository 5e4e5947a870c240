// ReducedModel: construction (cubature gradients, surface rows) and kinematics.
#include "reduced_model.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "dense_kernels.h"

namespace softrom {

ReducedModel::ReducedModel(const TetMesh& mesh, const StableNeoHookean& material,
                           const VecX& mass, const MatX& basis,
                           const std::vector<int>& cubature_elements,
                           const std::vector<double>& cubature_weights,
                           const std::vector<int>& surface_nodes,
                           const std::vector<std::array<int, 3>>& surface_faces)
    : num_nodes_(mesh.num_nodes),
      basis_cols_(basis.cols()),
      material_(material),
      surface_nodes_(surface_nodes),
      basis_(basis),
      tets_(mesh.tets),
      rest_(mesh.rest) {
  inv_rest_det_.reserve(mesh.volume.size());
  for (const double v : mesh.volume) inv_rest_det_.push_back(1.0 / (6.0 * v));
  const int md = elastic_dim();
  total_mass_ = mass.sum();
  rest_com_.setZero();
  for (int i = 0; i < num_nodes_; ++i) rest_com_ += mass[i] * mesh.rest.segment<3>(3 * i);
  rest_com_ /= total_mass_;

  const Eigen::Index nk = static_cast<Eigen::Index>(cubature_elements.size());
  grad_.resize(9 * nk, md);
  wvol_.reserve(nk);
  for (Eigen::Index k = 0; k < nk; ++k) {
    const int e = cubature_elements[k];
    // B_r's columns past the translations (rotations and deformation: q_e's).
    grad_.middleRows(9 * k, 9) =
        dfdx(mesh.dm_inv[e]) * element_rows(mesh.tets[e], basis.rightCols(md));
    wvol_.push_back(cubature_weights[k] * mesh.volume[e]);
  }
  grad_fast_.setZero(9 * nk, (md + 3) / 4 * 4);  // a multiple of 4: dense_kernels.h
  grad_fast_.leftCols(md) = grad_;
  const Eigen::Index groups = (nk + 3) / 4;
  grad_lanes_.assign(static_cast<std::size_t>(36 * md * groups), 0.0);
  wvol_lanes_.assign(static_cast<std::size_t>(4 * groups), 0.0);
  for (Eigen::Index k = 0; k < nk; ++k) {
    const Eigen::Index g = k / 4, l = k % 4;
    wvol_lanes_[4 * g + l] = wvol_[k];
    for (Eigen::Index j = 0; j < md; ++j)
      for (int i = 0; i < 9; ++i) grad_lanes_[36 * (g * md + j) + 4 * i + l] = grad_(9 * k + i, j);
  }

  const int ns = static_cast<int>(surface_nodes.size());
  surface_rows_.resize(3 * ns, basis.cols());
  normal_rows_.resize(ns, basis.cols());
  surface_rest_.resize(3 * ns);
  node_mass_surface_.resize(ns);
  std::vector<int> local(num_nodes_, -1);
  for (int c = 0; c < ns; ++c) {
    const int i = surface_nodes[c];
    local[i] = c;
    surface_rows_.middleRows(3 * c, 3) = basis.middleRows(3 * i, 3);
    normal_rows_.row(c) = basis.row(3 * i + 2);
    surface_rest_.segment<3>(3 * c) = mesh.rest.segment<3>(3 * i);
    node_mass_surface_[c] = mass[i];
  }
  normal_cols_ = normal_rows_;
  normal_row_norms_ = normal_rows_.rowwise().norm();
  surface_deform_norms_.resize(ns);
  for (int c = 0; c < ns; ++c)
    surface_deform_norms_[c] =
        surface_rows_.block(3 * c, kRigid, 3, basis.cols() - kRigid).norm();
  surface_cols_ = surface_rows_;
  faces_.reserve(surface_faces.size());
  for (const auto& f : surface_faces) {
    std::array<int, 3> lf{local[f[0]], local[f[1]], local[f[2]]};
    if (lf[0] < 0 || lf[1] < 0 || lf[2] < 0)
      throw std::invalid_argument("surface_faces uses a node that is not in surface_nodes");
    faces_.push_back(lf);
  }
  face_rows_.resize(3 * static_cast<Eigen::Index>(faces_.size()), basis.cols());
  for (size_t t = 0; t < faces_.size(); ++t) {
    const auto& f = faces_[t];
    face_rows_.middleRows(3 * t, 3) = (surface_rows_.middleRows(3 * f[0], 3) +
                                       surface_rows_.middleRows(3 * f[1], 3) +
                                       surface_rows_.middleRows(3 * f[2], 3)) /
                                      3.0;
  }
  face_corners_.reserve(3 * faces_.size());
  for (const auto& f : faces_)
    for (int k = 0; k < 3; ++k) face_corners_.push_back(3 * static_cast<std::ptrdiff_t>(f[k]));
  face_rows_pad_ = RowMatX::Zero(face_rows_.rows(), (face_rows_.cols() + 3) / 4 * 4);
  face_rows_pad_.leftCols(face_rows_.cols()) = face_rows_;
  if (ns > 0) {
    const double z_min = surface_rest_(Eigen::seqN(2, ns, 3)).minCoeff();
    int on_ground = 0;
    for (int c = 0; c < ns; ++c) on_ground += surface_rest_[3 * c + 2] <= z_min + 1e-6;
    rest_contacts_ = std::max(1, on_ground);
  }
  control_basis_ = MatX::Zero(deformation_dim(), 0);
  k_rest_ = elastic_stiffness(VecX::Zero(md), false);
  rest_about_com_ = rest_;
  for (int i = 0; i < num_nodes_; ++i) rest_about_com_.segment<3>(3 * i) -= rest_com_;
  floating_ = FloatingCoefficients::build(rest_about_com_, mass, total_mass_,
                                          basis.rightCols(deformation_dim()));
}

ReducedModel::WorkspaceLease ReducedModel::lend_workspace() const {
  {
    std::lock_guard<std::mutex> lock(workspace_mutex_);
    if (!idle_workspaces_.empty()) {
      std::unique_ptr<Workspace> ws = std::move(idle_workspaces_.back());
      idle_workspaces_.pop_back();
      return WorkspaceLease(*this, std::move(ws));
    }
  }
  auto ws = std::make_unique<Workspace>();
  ws->lender = this;
  return WorkspaceLease(*this, std::move(ws));
}

ReducedModel::WorkspaceLease::~WorkspaceLease() {
  std::lock_guard<std::mutex> lock(model_.workspace_mutex_);
  // (push_back allocates only when more are out at once than ever before.)
  model_.idle_workspaces_.push_back(std::move(ws_));
}

ReducedState ReducedModel::rest_state() const {
  ReducedState s;
  s.q = VecX::Zero(basis_cols_);
  s.qdot = VecX::Zero(basis_cols_);
  s.impulses = VecX::Zero(3 * surface_nodes_.size());
  return s;
}

VecX ReducedModel::positions(const VecX& q) const {
  if (config.frame == Frame::Linear) return rest_ + basis_ * q;
  // x_i = c + R (X_i + U_i z).
  const Mat3 rot = rotation_matrix(q.segment<3>(3));
  const Vec3 c = com(q);
  const VecX r = rest_about_com_ + basis_.rightCols(deformation_dim()) * q.tail(deformation_dim());
  VecX x(r.size());
  for (int i = 0; i < num_nodes_; ++i) x.segment<3>(3 * i) = c + rot * r.segment<3>(3 * i);
  return x;
}

double ReducedModel::min_volume_ratio(const VecX& q) const {
  // (Called on every env step, where it was 5-7 % of a walker's. The nodes come from the
  // dispatched column kernel rather than Eigen's SSE2 product, and the determinants from scalar
  // corner arithmetic as in drag_fast; together about 1.3x the earlier form's rate (best of
  // alternating runs, quadruped and cross). det F does not depend on the rotation, so the
  // floating frame's nodes are taken in the body frame, X + U z.)
  const Eigen::Index n3 = basis_.rows();
  VecX x(n3);
  if (config.frame == Frame::Linear) {
    kernels::cols_times(basis_.data(), n3, basis_cols_, q.data(), x.data());
    x += rest_;
  } else {
    kernels::cols_times(basis_.data() + kRigid * n3, n3, deformation_dim(), q.data() + kRigid,
                        x.data());
    x += rest_about_com_;
  }
  double j_min = std::numeric_limits<double>::infinity();
  const double* p = x.data();
  for (std::size_t e = 0; e < tets_.size(); ++e) {
    const Tet& t = tets_[e];
    const double* p0 = p + 3 * t[0];
    const double* p1 = p + 3 * t[1];
    const double* p2 = p + 3 * t[2];
    const double* p3 = p + 3 * t[3];
    const double a0 = p1[0] - p0[0], a1 = p1[1] - p0[1], a2 = p1[2] - p0[2];
    const double b0 = p2[0] - p0[0], b1 = p2[1] - p0[1], b2 = p2[2] - p0[2];
    const double c0 = p3[0] - p0[0], c1 = p3[1] - p0[1], c2 = p3[2] - p0[2];
    const double det = a0 * (b1 * c2 - b2 * c1) + a1 * (b2 * c0 - b0 * c2) +
                       a2 * (b0 * c1 - b1 * c0);
    j_min = std::min(j_min, det * inv_rest_det_[e]);
  }
  return j_min;
}

Vec3 ReducedModel::com_velocity(const VecX& qdot) const {
  return qdot.head<3>() / std::sqrt(total_mass_);
}

Vec3 ReducedModel::com(const VecX& q) const {
  return rest_com_ + q.head<3>() / std::sqrt(total_mass_);
}

}  // namespace softrom
