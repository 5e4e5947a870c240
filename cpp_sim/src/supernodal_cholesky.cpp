#include "supernodal_cholesky.h"

#include <algorithm>
#include <stdexcept>

namespace softrom {

namespace {

using Panel = Eigen::Map<Eigen::MatrixXd>;
using ConstPanel = Eigen::Map<const Eigen::MatrixXd>;

}  // namespace

void SupernodalLLT::analyze(const SpMat& upper) {
  const int n = static_cast<int>(upper.rows());
  if (upper.cols() != n || !upper.isCompressed())
    throw std::invalid_argument("SupernodalLLT: expected a square compressed matrix");
  n_ = n;
  const int* ap = upper.outerIndexPtr();
  const int* ai = upper.innerIndexPtr();
  for (int c = 0; c < n; ++c)
    for (int p = ap[c]; p < ap[c + 1]; ++p)
      if (ai[p] > c) throw std::invalid_argument("SupernodalLLT: entry below the diagonal");

  // Elimination tree (Liu's algorithm with path compression). Column k of `upper` is row k of
  // the lower triangle.
  std::vector<int> parent(n, -1), ancestor(n, -1);
  for (int k = 0; k < n; ++k)
    for (int p = ap[k]; p < ap[k + 1]; ++p)
      for (int i = ai[p], next; i != -1 && i < k; i = next) {
        next = ancestor[i];
        ancestor[i] = k;
        if (next == -1) parent[i] = k;
      }

  // Structure of L column by column: row k of L holds the etree paths from each i < k with
  // A(i, k) != 0 up to k. Rows are appended in increasing k, so every column comes out sorted.
  std::vector<std::vector<int>> col_rows(n);
  std::vector<int> mark(n, -1);
  for (int k = 0; k < n; ++k) {
    col_rows[k].push_back(k);
    mark[k] = k;
    for (int p = ap[k]; p < ap[k + 1]; ++p)
      for (int i = ai[p]; i < k && mark[i] != k; i = parent[i]) {
        col_rows[i].push_back(k);
        mark[i] = k;
      }
  }

  // Fundamental supernodes: column j joins j - 1's supernode when j is j - 1's parent and
  // column j - 1's structure is column j's plus the diagonal.
  first_col_.assign(1, 0);
  for (int j = 1; j < n; ++j)
    if (!(parent[j - 1] == j && col_rows[j - 1].size() == col_rows[j].size() + 1))
      first_col_.push_back(j);
  first_col_.push_back(n);
  const int ns = num_supernodes();
  supernode_of_col_.resize(n);
  row_ptr_.assign(1, 0);
  value_ptr_.assign(1, 0);
  rows_.clear();
  for (int s = 0; s < ns; ++s) {
    const int f = first_col_[s], ncols = first_col_[s + 1] - f;
    for (int j = f; j < f + ncols; ++j) supernode_of_col_[j] = s;
    rows_.insert(rows_.end(), col_rows[f].begin(), col_rows[f].end());
    row_ptr_.push_back(static_cast<int>(rows_.size()));
    value_ptr_.push_back(value_ptr_.back() +
                         static_cast<Eigen::Index>(col_rows[f].size()) * ncols);
  }

  // Where each stored entry (r, c), r <= c, of `upper` goes: L's column r, row c.
  input_slot_.resize(upper.nonZeros());
  for (int c = 0; c < n; ++c)
    for (int p = ap[c]; p < ap[c + 1]; ++p) {
      const int r = ai[p], s = supernode_of_col_[r];
      const int* begin = rows_.data() + row_ptr_[s];
      const int* end = rows_.data() + row_ptr_[s + 1];
      const int pos = static_cast<int>(std::lower_bound(begin, end, c) - begin);
      input_slot_[p] = value_ptr_[s] + static_cast<Eigen::Index>(r - first_col_[s]) *
                                           (row_ptr_[s + 1] - row_ptr_[s]) + pos;
    }

  // Scratch: an update block is at most (rows of a supernode) x (columns of one).
  size_t max_rows = 0, max_cols = 0;
  for (int s = 0; s < ns; ++s) {
    max_rows = std::max<size_t>(max_rows, row_ptr_[s + 1] - row_ptr_[s]);
    max_cols = std::max<size_t>(max_cols, first_col_[s + 1] - first_col_[s]);
  }
  max_update_ = max_rows * max_cols;
  values_.assign(value_ptr_.back(), 0.0);
  relative_.assign(n, 0);
  head_.assign(ns, -1);
  link_.assign(ns, -1);
  next_row_.assign(ns, 0);
  update_.resize(static_cast<Eigen::Index>(max_update_));
  gather_.resize(static_cast<Eigen::Index>(max_rows));
}

bool SupernodalLLT::factorize(const SpMat& upper) {
  const int ns = num_supernodes();
  std::fill(values_.begin(), values_.end(), 0.0);
  const double* av = upper.valuePtr();
  for (size_t p = 0; p < input_slot_.size(); ++p) values_[input_slot_[p]] = av[p];
  std::fill(head_.begin(), head_.end(), -1);

  for (int s = 0; s < ns; ++s) {
    const int f = first_col_[s], l = first_col_[s + 1], ncols = l - f;
    const int* rows = rows_.data() + row_ptr_[s];
    const int nrows = row_ptr_[s + 1] - row_ptr_[s];
    Panel ls(values_.data() + value_ptr_[s], nrows, ncols);
    for (int k = 0; k < nrows; ++k) relative_[rows[k]] = k;

    // Left-looking: subtract the update of every earlier supernode d with rows in [f, l).
    for (int d = head_[s]; d != -1;) {
      const int next_d = link_[d];
      const int* drows = rows_.data() + row_ptr_[d];
      const int dn = row_ptr_[d + 1] - row_ptr_[d];
      const int dcols = first_col_[d + 1] - first_col_[d];
      const int p1 = next_row_[d];
      int p2 = p1;
      while (p2 < dn && drows[p2] < l) ++p2;
      const int m = dn - p1, k = p2 - p1;
      ConstPanel ld(values_.data() + value_ptr_[d], dn, dcols);
      Panel c(update_.data(), m, k);
      c.noalias() = ld.bottomRows(m) * ld.middleRows(p1, k).transpose();
      for (int jj = 0; jj < k; ++jj) {
        double* col = ls.col(drows[p1 + jj] - f).data();
        const double* cj = c.col(jj).data();
        for (int ii = jj; ii < m; ++ii) col[relative_[drows[p1 + ii]]] -= cj[ii];
      }
      if (p2 < dn) {
        next_row_[d] = p2;
        const int t = supernode_of_col_[drows[p2]];
        link_[d] = head_[t];
        head_[t] = d;
      }
      d = next_d;
    }

    Eigen::Ref<Eigen::MatrixXd> diag = ls.topRows(ncols);
    Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(diag);
    if (llt.info() != Eigen::Success) return false;
    if (nrows > ncols)
      diag.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(
          ls.bottomRows(nrows - ncols));
    if (nrows > ncols) {
      next_row_[s] = ncols;
      const int t = supernode_of_col_[rows[ncols]];
      link_[s] = head_[t];
      head_[t] = s;
    }
  }
  return true;
}

void SupernodalLLT::solve_in_place(Eigen::VectorXd& x) const {
  const int ns = num_supernodes();
  for (int s = 0; s < ns; ++s) {  // L y = b
    const int f = first_col_[s], ncols = first_col_[s + 1] - f;
    const int* rows = rows_.data() + row_ptr_[s];
    const int below = row_ptr_[s + 1] - row_ptr_[s] - ncols;
    // Eigen's triangular solvers want a writable panel; solving never writes to it.
    Panel ls(const_cast<double*>(values_.data()) + value_ptr_[s], ncols + below, ncols);
    auto xs = x.segment(f, ncols);
    ls.topRows(ncols).triangularView<Eigen::Lower>().solveInPlace(xs);
    if (below > 0) {
      gather_.head(below).noalias() = ls.bottomRows(below) * xs;
      for (int k = 0; k < below; ++k) x[rows[ncols + k]] -= gather_[k];
    }
  }
  for (int s = ns - 1; s >= 0; --s) {  // L^T x = y
    const int f = first_col_[s], ncols = first_col_[s + 1] - f;
    const int* rows = rows_.data() + row_ptr_[s];
    const int below = row_ptr_[s + 1] - row_ptr_[s] - ncols;
    // Eigen's triangular solvers want a writable panel; solving never writes to it.
    Panel ls(const_cast<double*>(values_.data()) + value_ptr_[s], ncols + below, ncols);
    auto xs = x.segment(f, ncols);
    if (below > 0) {
      for (int k = 0; k < below; ++k) gather_[k] = x[rows[ncols + k]];
      xs.noalias() -= ls.bottomRows(below).transpose() * gather_.head(below);
    }
    ls.topRows(ncols).triangularView<Eigen::Lower>().transpose().solveInPlace(xs);
  }
}

}  // namespace softrom
