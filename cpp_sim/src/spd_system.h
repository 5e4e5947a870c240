// The symmetric positive-definite 3N x 3N systems of a tetrahedral mesh (the implicit-Euler
// Newton matrix M/dt^2 + K(x) + D/dt and its parts), stored once and refilled in place.
#pragma once

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <vector>

#include "supernodal_cholesky.h"
#include "tet_mesh.h"

namespace softrom {

using SpMat = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

enum class Factorization { kSimplicialLLT, kSimplicialLDLT, kSupernodalLLT };

// A symmetric matrix on the couplings of a tet mesh, kept as the upper triangle of P A P^T with
// P a fill-reducing ordering of the nodes (AMD on the node graph, each node's three DOFs
// consecutive). Every matrix on the mesh shares this pattern, so element blocks scatter straight
// into a values array through precomputed slots, and the Cholesky factorisation's symbolic
// analysis (elimination tree, column counts) runs once, however many numeric factorisations
// follow. Vectors passed in and out use the mesh's own DOF numbering (3 * node + axis).
class SpdSystem {
 public:
  static constexpr int kElementEntries = 78;  // upper triangle of a 12 x 12 element block

  explicit SpdSystem(const TetMesh& mesh);

  int size() const { return static_cast<int>(matrix_.rows()); }
  Eigen::Index nonzeros() const { return matrix_.nonZeros(); }
  // Slots into a values array of the upper triangle of element e's 12 x 12 block, in the order
  // (p, q), p <= q, row by row; local index p = 3 a + i is the tet's node a, axis i.
  const int* element_slots(int e) const { return &element_slots_[kElementEntries * e]; }
  int diagonal_slot(int dof) const { return diagonal_slots_[dof]; }

  // y = A x for the symmetric A whose stored upper triangle is `values`.
  void multiply(const std::vector<double>& values, const VecX& x, VecX& y) const;

  // The values of the matrix to factorise; fill them, then call factorize.
  double* values() { return matrix_.valuePtr(); }
  // Makes every row and column of a fixed node's DOFs those of the identity.
  void clamp(const std::vector<char>& fixed_node);
  // Numeric factorisation; the symbolic analysis of `kind` happens on its first use only.
  // Throws std::runtime_error when the factorisation breaks down (a zero or negative pivot).
  void factorize(Factorization kind);
  // x = A^{-1} b with the latest factorisation.
  void solve(const VecX& b, VecX& x);
  // Entries of the Cholesky factor of the latest factorisation (fill-in included).
  Eigen::Index factor_nonzeros() const;

 private:
  SpMat matrix_;                     // upper triangle of P A P^T, column-compressed
  std::vector<int> old_of_new_;      // DOF numbering: permuted position -> mesh DOF
  std::vector<int> element_slots_;   // kElementEntries per tet
  std::vector<int> diagonal_slots_;  // per mesh DOF
  Eigen::SimplicialLLT<SpMat, Eigen::Upper, Eigen::NaturalOrdering<int>> llt_;
  Eigen::SimplicialLDLT<SpMat, Eigen::Upper, Eigen::NaturalOrdering<int>> ldlt_;
  SupernodalLLT supernodal_;
  bool llt_analysed_ = false;
  bool ldlt_analysed_ = false;
  bool supernodal_analysed_ = false;
  bool factorized_ = false;
  Factorization last_ = Factorization::kSimplicialLLT;
  VecX permuted_b_, permuted_x_;
};

}  // namespace softrom
