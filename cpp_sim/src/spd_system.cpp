#include "spd_system.h"

#include <Eigen/OrderingMethods>
#include <algorithm>
#include <stdexcept>

namespace softrom {

namespace {

// Fill-reducing order of the nodes: AMD on the node adjacency graph. Ordering nodes rather than
// DOFs keeps each node's 3 x 3 blocks dense in the factor and makes the analysis 9x smaller.
std::vector<int> node_order(const TetMesh& mesh) {
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(mesh.tets.size() * 16);
  for (const Tet& t : mesh.tets)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) trip.emplace_back(t[a], t[b], 1.0);
  SpMat graph(mesh.num_nodes, mesh.num_nodes);
  graph.setFromTriplets(trip.begin(), trip.end());
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> perm;
  Eigen::AMDOrdering<int>()(graph, perm);
  // Eigen's orderings return the inverse permutation: entry k is the node eliminated k-th.
  return std::vector<int>(perm.indices().data(), perm.indices().data() + mesh.num_nodes);
}

}  // namespace

SpdSystem::SpdSystem(const TetMesh& mesh) {
  const int n = mesh.num_nodes;
  const std::vector<int> order = node_order(mesh);
  std::vector<int> new_of_old(3 * n);
  old_of_new_.resize(3 * n);
  for (int k = 0; k < n; ++k)
    for (int i = 0; i < 3; ++i) {
      old_of_new_[3 * k + i] = 3 * order[k] + i;
      new_of_old[3 * order[k] + i] = 3 * k + i;
    }

  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(mesh.tets.size() * kElementEntries + 3 * n);
  auto upper = [&](int p, int q) {
    const int r = new_of_old[p], c = new_of_old[q];
    return std::make_pair(std::min(r, c), std::max(r, c));
  };
  for (const Tet& t : mesh.tets)
    for (int p = 0; p < 12; ++p)
      for (int q = p; q < 12; ++q) {
        const auto [r, c] = upper(3 * t[p / 3] + p % 3, 3 * t[q / 3] + q % 3);
        trip.emplace_back(r, c, 0.0);
      }
  for (int d = 0; d < 3 * n; ++d) trip.emplace_back(d, d, 0.0);
  matrix_.resize(3 * n, 3 * n);
  matrix_.setFromTriplets(trip.begin(), trip.end());
  matrix_.makeCompressed();

  auto slot = [&](int p, int q) {
    const auto [r, c] = upper(p, q);
    const int* begin = matrix_.innerIndexPtr() + matrix_.outerIndexPtr()[c];
    const int* end = matrix_.innerIndexPtr() + matrix_.outerIndexPtr()[c + 1];
    return static_cast<int>(std::lower_bound(begin, end, r) - matrix_.innerIndexPtr());
  };
  element_slots_.resize(mesh.tets.size() * kElementEntries);
  for (size_t e = 0; e < mesh.tets.size(); ++e) {
    const Tet& t = mesh.tets[e];
    int* s = &element_slots_[e * kElementEntries];
    for (int p = 0; p < 12; ++p)
      for (int q = p; q < 12; ++q) *s++ = slot(3 * t[p / 3] + p % 3, 3 * t[q / 3] + q % 3);
  }
  diagonal_slots_.resize(3 * n);
  for (int d = 0; d < 3 * n; ++d) diagonal_slots_[d] = slot(d, d);
  permuted_b_.resize(3 * n);
  permuted_x_.resize(3 * n);
}

void SpdSystem::multiply(const std::vector<double>& values, const VecX& x, VecX& y) const {
  y.setZero(x.size());
  const int* outer = matrix_.outerIndexPtr();
  const int* inner = matrix_.innerIndexPtr();
  for (int c = 0; c < size(); ++c) {
    const int oc = old_of_new_[c];
    const double xc = x[oc];
    double yc = 0.0;
    for (int s = outer[c]; s < outer[c + 1]; ++s) {
      const int orow = old_of_new_[inner[s]];
      yc += values[s] * x[orow];
      if (inner[s] != c) y[orow] += values[s] * xc;
    }
    y[oc] += yc;
  }
}

void SpdSystem::clamp(const std::vector<char>& fixed_node) {
  const int* outer = matrix_.outerIndexPtr();
  const int* inner = matrix_.innerIndexPtr();
  double* val = matrix_.valuePtr();
  for (int c = 0; c < size(); ++c) {
    const bool col_fixed = fixed_node[old_of_new_[c] / 3] != 0;
    for (int s = outer[c]; s < outer[c + 1]; ++s)
      if (col_fixed || fixed_node[old_of_new_[inner[s]] / 3])
        val[s] = (inner[s] == c) ? 1.0 : 0.0;
  }
}

void SpdSystem::factorize(Factorization kind) {
  factorized_ = false;
  bool ok = false;
  if (kind == Factorization::kSimplicialLLT) {
    if (!llt_analysed_) llt_.analyzePattern(matrix_);
    llt_analysed_ = true;
    llt_.factorize(matrix_);
    ok = llt_.info() == Eigen::Success;
  } else if (kind == Factorization::kSupernodalLLT) {
    if (!supernodal_analysed_) supernodal_.analyze(matrix_);
    supernodal_analysed_ = true;
    ok = supernodal_.factorize(matrix_);
  } else {
    if (!ldlt_analysed_) ldlt_.analyzePattern(matrix_);
    ldlt_analysed_ = true;
    ldlt_.factorize(matrix_);
    // Eigen flags a zero pivot only; a negative one (an indefinite matrix) must fail too.
    ok = ldlt_.info() == Eigen::Success && ldlt_.vectorD().minCoeff() > 0.0;
  }
  if (!ok) throw std::runtime_error("implicit Euler: sparse factorisation failed");
  factorized_ = true;
  last_ = kind;
}

void SpdSystem::solve(const VecX& b, VecX& x) {
  for (int k = 0; k < size(); ++k) permuted_b_[k] = b[old_of_new_[k]];
  if (last_ == Factorization::kSimplicialLLT) {
    permuted_x_ = llt_.solve(permuted_b_);
  } else if (last_ == Factorization::kSupernodalLLT) {
    permuted_x_ = permuted_b_;
    supernodal_.solve_in_place(permuted_x_);
  } else {
    permuted_x_ = ldlt_.solve(permuted_b_);
  }
  x.resize(size());
  for (int k = 0; k < size(); ++k) x[old_of_new_[k]] = permuted_x_[k];
}

Eigen::Index SpdSystem::factor_nonzeros() const {
  if (!factorized_) return 0;
  // A copy, but this is a diagnostic, never on the stepping path.
  if (last_ == Factorization::kSimplicialLLT) return SpMat(llt_.matrixL()).nonZeros();
  if (last_ == Factorization::kSupernodalLLT) return supernodal_.factor_nonzeros();
  return SpMat(ldlt_.matrixL()).nonZeros() + size();  // the unit diagonal is implicit
}

}  // namespace softrom
