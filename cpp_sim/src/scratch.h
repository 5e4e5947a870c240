// Scratch matrices that keep their memory between steps.
//
// Eigen's dynamic matrices free and allocate on every change of size, and a contact step's
// sizes change with its candidate rows (from step to step), its loaded sets (from stagger to
// stagger) and its least-distance solves' passive sets. A rollout worker reuses one Workspace
// for every step it takes, so scratch that only grows lets it step without touching the heap
// once it has seen its largest sizes (the rule MuJoCo's mjData arena keeps for mj_step).
//
// Scratch<Plain> is an Eigen::Map of a Plain shape (MatX, RowMatX, VecX) over storage that
// only grows, so it can be used wherever Eigen takes a matrix expression or a Ref. Its
// resize(), setZero(n), assignment from an expression and noalias() assignment resize it as a
// Plain matrix would (a bare Map would silently write past its end: Eigen's size checks are off
// in release builds). Compound assignments (+=, -=) need equal sizes, as for a Plain matrix.
// Storage is Eigen-aligned and the Map says so, so Eigen's kernels (and their sums' order) are
// the same as on a Plain matrix of the same size.
#pragma once

#include <Eigen/Dense>
#include <algorithm>
#include <cstring>
#include <new>
#include <utility>

namespace softrom {

template <class Plain>
class Scratch : public Eigen::Map<Plain, Eigen::AlignedMax> {
 public:
  using Base = Eigen::Map<Plain, Eigen::AlignedMax>;
  using Index = Eigen::Index;
  static constexpr bool kVector = Plain::ColsAtCompileTime == 1;

  Scratch() : Base(nullptr, 0, kVector ? 1 : 0) {}
  // A Map's copy would point into the other's storage: copy by value instead.
  Scratch(const Scratch& other) : Scratch() { *this = other; }
  Scratch& operator=(const Scratch& other) {
    if (this != &other) {
      resize(other.rows(), other.cols());
      Base::operator=(other);
    }
    return *this;
  }

  // The shape rows x cols, contents unspecified (as Eigen's resize).
  void resize(Index rows, Index cols) {
    reserve(rows * cols);
    reseat(rows, cols);
  }
  void resize(Index n) {
    static_assert(kVector, "resize(n) is for vectors");
    resize(n, 1);
  }
  // The shape rows x cols keeping the old top-left block (only growth: rows, cols no smaller),
  // as Eigen's conservativeResize of a column-major matrix.
  void conservative_resize(Index rows, Index cols) {
    static_assert(!Plain::IsRowMajor, "column-major only");
    const Index r0 = this->rows(), c0 = this->cols();
    if (rows * cols > store_.size()) store_.conservativeResize(grown(rows * cols));
    // Columns move to their new stride from the last one back (the new stride is no
    // smaller, so no column overwrites one not yet moved).
    if (rows != r0)
      for (Index j = c0 - 1; j >= 0; --j)
        std::memmove(store_.data() + j * rows, store_.data() + j * r0, sizeof(double) * r0);
    reseat(rows, cols);
  }
  void setZero(Index n) {
    resize(n);
    Base::setZero();
  }
  using Base::setZero;
  void setIdentity(Index rows, Index cols) {
    resize(rows, cols);
    Base::setIdentity();
  }

  template <class Other>
  Scratch& operator=(const Eigen::DenseBase<Other>& other) {
    resize(other.rows(), other.cols());
    Base::operator=(other.derived());
    return *this;
  }
  using Base::operator+=;
  using Base::operator-=;
  using Base::operator*=;
  using Base::operator/=;

  // noalias() that resizes for `=` (Eigen's would not resize a Map).
  class NoAlias {
   public:
    explicit NoAlias(Scratch& s) : s_(s) {}
    template <class Other>
    Scratch& operator=(const Other& other) {
      s_.resize(other.rows(), other.cols());
      static_cast<Base&>(s_).noalias() = other;
      return s_;
    }
    template <class Other>
    Scratch& operator+=(const Other& other) {
      static_cast<Base&>(s_).noalias() += other;
      return s_;
    }
    template <class Other>
    Scratch& operator-=(const Other& other) {
      static_cast<Base&>(s_).noalias() -= other;
      return s_;
    }

   private:
    Scratch& s_;
  };
  NoAlias noalias() { return NoAlias(*this); }

  // Exchanges the two scratches' storage (O(1), as Plain::swap).
  void swap(Scratch& other) {
    const Index r = this->rows(), c = this->cols(), ro = other.rows(), co = other.cols();
    store_.swap(other.store_);
    reseat(ro, co);
    other.reseat(r, c);
  }

 private:
  // Geometric growth, so a size that creeps up step by step reallocates O(log) times.
  Index grown(Index n) const { return std::max<Index>({n, store_.size() + store_.size() / 2, 16}); }
  void reserve(Index n) {
    if (n > store_.size()) store_.resize(grown(n));  // contents not kept (as Eigen's resize)
  }
  void reseat(Index rows, Index cols) {
    // Re-pointing a Map by placement new is the idiom Eigen's documentation gives.
    if constexpr (kVector) {
      new (static_cast<Base*>(this)) Base(store_.data(), rows);
    } else {
      new (static_cast<Base*>(this)) Base(store_.data(), rows, cols);
    }
  }
  Eigen::VectorXd store_;  // Eigen's aligned allocation
};

using ScratchVec = Scratch<Eigen::VectorXd>;
using ScratchMat = Scratch<Eigen::MatrixXd>;
using ScratchRowMat =
    Scratch<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>;

}  // namespace softrom
