// Bindings of the fast solver's dense kernels and least-distance solves, for their tests.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <limits>
#include <sstream>
#include <string>

#include "dense_kernels.h"
#include "nnls.h"
#include "reduced_model.h"
#include "small_cholesky.h"

namespace py = pybind11;
using namespace softrom;

void bind_checks(py::module_& m) {
  m.def(
      "_kernel_cols_times",
      [](const Eigen::Ref<const MatX>& a, const Eigen::Ref<const VecX>& x) {
        if (x.size() != a.cols()) {
          std::ostringstream msg;
          msg << "x has " << x.size() << " entries, a has " << a.cols() << " columns";
          throw py::value_error(msg.str());
        }
        const MatX a_owned = a;  // exactly rows x cols, column-major: the kernel's layout
        VecX out(a.rows());
        kernels::cols_times(a_owned.data(), a.rows(), a.cols(), x.data(), out.data());
        return out;
      },
      py::arg("a"), py::arg("x"),
      "A x through the fast solver's matrix-vector kernel (for its tests).");

  m.def(
      "_kernel_cols_dot",
      [](const Eigen::Ref<const MatX>& a, const Eigen::Ref<const VecX>& x) {
        if (x.size() != a.rows()) {
          std::ostringstream msg;
          msg << "x has " << x.size() << " entries, a has " << a.rows() << " rows";
          throw py::value_error(msg.str());
        }
        const MatX a_owned = a;  // exactly rows x cols, column-major: the kernel's layout
        VecX out(a.cols());
        kernels::cols_dot(a_owned.data(), a.rows(), a.cols(), x.data(), out.data());
        return out;
      },
      py::arg("a"), py::arg("x"),
      "A^T x through the fast solver's column-dot kernel (for its tests).");

  m.def(
      "_kernel_cols_times_pair",
      [](const Eigen::Ref<const MatX>& a, const Eigen::Ref<const VecX>& x,
         const Eigen::Ref<const VecX>& y) {
        if (x.size() != a.cols() || y.size() != a.cols()) {
          std::ostringstream msg;
          msg << "x and y have " << x.size() << " and " << y.size() << " entries, a has "
              << a.cols() << " columns";
          throw py::value_error(msg.str());
        }
        const MatX a_owned = a;
        VecX out_x(a.rows()), out_y(a.rows());
        kernels::cols_times_pair(a_owned.data(), a.rows(), a.cols(), x.data(), y.data(),
                                 out_x.data(), out_y.data());
        return py::make_tuple(out_x, out_y);
      },
      py::arg("a"), py::arg("x"), py::arg("y"),
      "(A x, A y) through the fast solver's one-pass kernel (for its tests).");

  m.def(
      "_kernel_cols_dot_times",
      [](const Eigen::Ref<const MatX>& a, const Eigen::Ref<const VecX>& x) {
        if (x.size() != a.rows()) {
          std::ostringstream msg;
          msg << "x has " << x.size() << " entries, a has " << a.rows() << " rows";
          throw py::value_error(msg.str());
        }
        const MatX a_owned = a;
        VecX dots(a.cols()), out(a.rows());
        kernels::cols_dot_times(a_owned.data(), a.rows(), a.cols(), x.data(), dots.data(),
                                out.data());
        return py::make_tuple(dots, out);
      },
      py::arg("a"), py::arg("x"),
      "(A^T x, A A^T x) through the fast solver's fused kernel (for its tests).");

  m.def(
      "_kernel_cholesky",
      [](const Eigen::Ref<const MatX>& a, const Eigen::Ref<const VecX>& b) {
        const Eigen::Index n = a.rows();
        if (a.cols() != n || b.size() != n) {
          std::ostringstream msg;
          msg << "need a square a and b of its size; got a " << a.rows() << " x " << a.cols()
              << " and b of " << b.size();
          throw py::value_error(msg.str());
        }
        // As the primal friction half calls them: the lower kernel on a copy with three zero
        // rows of padding (returned with the factor, so a test sees them kept), the scalar
        // loops on the upper triangle; each factor then solves A x = b.
        MatX lower = MatX::Zero(n + 3, n), upper = a;
        lower.topRows(n).triangularView<Eigen::Lower>() = a;
        VecX x_lower = b, x_upper = b;
        const bool lower_ok = kernels::cholesky_lower(lower.data(), n, n + 3);
        if (lower_ok) small::cholesky_lower_solve(lower.data(), n, n + 3, x_lower.data());
        const bool upper_ok = small::cholesky_upper(upper.data(), n, n);
        if (upper_ok) small::cholesky_upper_solve(upper.data(), n, n, x_upper.data());
        return py::make_tuple(lower_ok, lower, x_lower, upper_ok, upper, x_upper);
      },
      py::arg("a"), py::arg("b"),
      "(ok, L padded with 3 rows, x, ok, U, x): A = L L^T by the lower Cholesky kernel and "
      "A = U^T U by the scalar loops, each with its solve of A x = b (for their tests).");

  m.def(
      "_least_distance_sequence",
      [](const Eigen::Ref<const MatX>& e, const Eigen::Ref<const MatX>& fs,
         const std::string& solver) {
        const Eigen::Index k = e.rows(), m = e.cols();
        if (k < 1 || m < 1 || fs.cols() != k) {
          std::ostringstream msg;
          msg << "need e (k x m, k, m >= 1) and fs (S x k); got e " << k << " x " << m
              << " and fs " << fs.rows() << " x " << fs.cols();
          throw py::value_error(msg.str());
        }
        if (solver != "fast" && solver != "reference")
          throw py::value_error("solver must be 'fast' or 'reference', got '" + solver + "'");
        // (The contact solve's rows are finite by construction; an inf here was answered
        // "feasible, converged" at x = 0.)
        if (!e.allFinite() || !fs.allFinite())
          throw py::value_error("e and fs must be finite");
        // As the contact solve calls it: g = [E^T; f^T] with only f changing from call to call,
        // the last call's multipliers as the warm start, and (fast) G^T kept and the factor
        // carried over.
        const bool fast = solver == "fast";
        MatX g(m + 1, k), gt(k, m + 1);
        g.topRows(m) = e.transpose();
        gt.leftCols(m) = e;
        NnlsWorkspace ws;
        VecX lambda = VecX::Zero(k), x(m);
        py::list out;
        for (Eigen::Index s = 0; s < fs.rows(); ++s) {
          g.row(m) = fs.row(s);
          gt.col(m) = fs.row(s).transpose();
          bool converged = true;
          // least_distance writes x only when the programme is feasible.
          x.setConstant(std::numeric_limits<double>::quiet_NaN());
          const bool ok = least_distance(g, x, lambda, converged,
                                         fast ? NnlsSolve::Gram : NnlsSolve::Qr, ws,
                                         fast ? gt.data() : nullptr, fast);
          out.append(py::make_tuple(VecX(x), VecX(lambda), ok, converged));
        }
        return out;
      },
      py::arg("e"), py::arg("fs"), py::arg("solver") = "fast",
      "The least-distance programmes min |x| s.t. E x >= f for each row f of fs, solved in "
      "sequence as the staggered projection's normal half solves them (warm-started, and "
      "with the fast solver the NNLS factor carried over): a list of (x, lambda, feasible, "
      "converged), x NaN where infeasible (for its tests).");
}
