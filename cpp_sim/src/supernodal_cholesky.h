// Supernodal sparse Cholesky factorisation A = L L^T, left-looking, with dense blocks.
//
// Columns of L that share their sparsity below the diagonal (a node's three DOFs, and the
// separators near the top of the elimination tree) are grouped into supernodes and stored as
// dense column-major panels, so the factorisation runs as dense matrix products (Eigen's
// blocked GEMM, LLT and triangular solves) instead of the scalar, indirectly indexed updates
// of a simplicial factorisation. The matrix is taken as already fill-reduce ordered.
//
// Why our own: CHOLMOD would be the usual choice, but scikit-sparse ships no wheels (its sdist
// builds against a system SuiteSparse) and Eigen's CholmodSupport / PardisoSupport link
// external libraries, none of which a pip-only install has. Measured on the quadruped's Newton
// matrix (4,236 DOFs, AMD), one thread: Eigen SimplicialLDLT / LLT ~33 ms per factorisation,
// CHOLMOD supernodal with OpenBLAS (AVX2) ~22 ms, this class ~11 ms.
#pragma once

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <vector>

namespace softrom {

class SupernodalLLT {
 public:
  using SpMat = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

  // Symbolic analysis of the symmetric matrix whose upper triangle (diagonal included) is
  // stored column-compressed in `upper`: elimination tree, the structure of L, supernodes.
  void analyze(const SpMat& upper);
  // Numeric factorisation of a matrix with the analysed pattern. False when a pivot is not
  // positive (the matrix is not positive definite); L is then unusable.
  bool factorize(const SpMat& upper);
  // x := A^{-1} x with the latest factorisation.
  void solve_in_place(Eigen::VectorXd& x) const;

  int size() const { return n_; }
  int num_supernodes() const { return static_cast<int>(first_col_.size()) - 1; }
  // Stored entries of L (dense panels, so a few explicit zeros are counted).
  Eigen::Index factor_nonzeros() const { return static_cast<Eigen::Index>(values_.size()); }

 private:
  int n_ = 0;
  std::vector<int> first_col_;  // supernode s holds columns [first_col_[s], first_col_[s + 1])
  std::vector<int> row_ptr_;    // rows of s: rows_[row_ptr_[s] .. row_ptr_[s + 1]), sorted
  std::vector<int> rows_;
  std::vector<Eigen::Index> value_ptr_;  // s's panel: nrows x ncols column-major at value_ptr_[s]
  std::vector<int> supernode_of_col_;
  std::vector<Eigen::Index> input_slot_;  // upper's k-th stored entry -> its place in values_
  size_t max_update_ = 0;                 // largest update block, entries
  std::vector<double> values_;
  // Factorisation scratch, kept to avoid allocating per call.
  std::vector<int> relative_, head_, link_, next_row_;
  Eigen::VectorXd update_;
  mutable Eigen::VectorXd gather_;
};

}  // namespace softrom
