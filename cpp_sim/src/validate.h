// Argument validation for the binding layer: every public entry point converts and checks its
// numpy inputs here, so the C++ core below can assume well-formed data. Errors name the
// argument, what was expected and what was given.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <Eigen/Dense>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "tet_mesh.h"

namespace softrom::validate {

namespace py = pybind11;

inline std::string shape_str(const py::array& a) {
  std::ostringstream s;
  s << "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) s << (i ? ", " : "") << a.shape(i);
  if (a.ndim() == 1) s << ",";
  s << ")";
  return s.str();
}

inline py::array as_array(py::handle obj, const char* name) {
  if (obj.is_none()) throw py::type_error(std::string(name) + " must be an array, got None");
  py::array a = py::array::ensure(obj);
  if (!a) throw py::type_error(std::string(name) + " must be array-like");
  return a;
}

inline void require_real(const py::array& a, const char* name) {
  const char kind = a.dtype().kind();
  if (kind != 'f' && kind != 'i' && kind != 'u')
    throw py::type_error(std::string(name) + " must hold real numbers, got dtype " +
                         std::string(py::str(a.dtype())));
}

// A finite float64 array of shape (rows, cols) (rows = -1: any), returned flattened row-major.
inline VecX real_matrix(py::handle obj, const char* name, py::ssize_t rows, py::ssize_t cols) {
  py::array a = as_array(obj, name);
  require_real(a, name);
  if (a.ndim() != 2 || a.shape(1) != cols || (rows >= 0 && a.shape(0) != rows)) {
    std::ostringstream msg;
    msg << name << " has shape " << shape_str(a) << ", expected (";
    if (rows >= 0)
      msg << rows;
    else
      msg << "N";
    msg << ", " << cols << ")";
    throw py::value_error(msg.str());
  }
  auto c = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(a);
  const double* p = c.data();
  const py::ssize_t n = c.size();
  for (py::ssize_t i = 0; i < n; ++i)
    if (!std::isfinite(p[i])) {
      std::ostringstream msg;
      msg << name << " contains a non-finite value (" << p[i] << ") at row " << i / cols;
      throw py::value_error(msg.str());
    }
  return Eigen::Map<const VecX>(p, n);
}

inline std::vector<Tet> tet_array(py::handle obj, const char* name) {
  py::array a = as_array(obj, name);
  const char kind = a.dtype().kind();
  if (kind != 'i' && kind != 'u')
    throw py::type_error(std::string(name) + " must be an integer array, got dtype " +
                         std::string(py::str(a.dtype())));
  if (a.ndim() != 2 || a.shape(1) != 4 || a.shape(0) < 1)
    throw py::value_error(std::string(name) + " has shape " + shape_str(a) +
                          ", expected (T, 4) with T >= 1");
  auto c = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(a);
  std::vector<Tet> tets(static_cast<size_t>(a.shape(0)));
  const int64_t* p = c.data();
  for (size_t e = 0; e < tets.size(); ++e)
    for (int k = 0; k < 4; ++k) {
      const int64_t v = p[4 * e + k];
      if (v < 0 || v > INT32_MAX) {
        std::ostringstream msg;
        msg << name << "[" << e << "] has node index " << v << " out of range";
        throw py::value_error(msg.str());
      }
      tets[e][k] = static_cast<int32_t>(v);
    }
  return tets;
}

// True for Python's bool and numpy's (numpy.bool_ is no subclass of bool, but converts to 1.0
// or 0.0 like one).
inline bool is_bool(py::handle x) {
  return py::isinstance<py::bool_>(x) ||
         py::isinstance(x, py::module_::import("numpy").attr("bool_"));
}

// A constructor's real-number argument, converted as a double argument is (so its stub reads
// the same), remembering whether it came as a bool: pybind11 converts True to 1.0, and
// FEMModel(nodes, tets, True, 0.3, True) built a 1 Pa, 1 kg/m^3 model.
struct RealArgument {
  double value = 0.0;
  bool was_bool = false;
  // The value, or TypeError naming the argument when it was a bool.
  double get(const char* name) const {
    if (was_bool)
      throw py::type_error(std::string(name) + " must be a real number, got " +
                           (value != 0.0 ? "True" : "False"));
    return value;
  }
};

// A Python real number (numpy's too) as a double, never a bool (Python's or numpy's), or
// TypeError naming the setting.
inline double real(py::handle x, const char* name) {
  if (!is_bool(x)) {
    try {
      return x.cast<double>();
    } catch (const py::cast_error&) {
    }
  }
  throw py::type_error(std::string(name) + " must be a real number, got " +
                       std::string(py::repr(x)));
}

// A Python integer (numpy's too: __index__), never a bool, within [low, high], or an error
// naming the setting.
inline int integer_at_least(py::handle x, const char* name, int low,
                            int high = std::numeric_limits<int>::max()) {
  if (py::isinstance<py::bool_>(x) || !PyIndex_Check(x.ptr()))
    throw py::type_error(std::string(name) + " must be an integer, got " +
                         std::string(py::repr(x)));
  const py::object index = py::reinterpret_steal<py::object>(PyNumber_Index(x.ptr()));
  if (!index) throw py::error_already_set();
  int overflow = 0;
  const long long wide = PyLong_AsLongLongAndOverflow(index.ptr(), &overflow);
  if (overflow > 0 || wide > high)
    throw py::value_error(std::string(name) + " must be at most " + std::to_string(high) +
                          ", got " + std::string(py::repr(x)));
  if (overflow < 0 || wide < low)
    throw py::value_error(std::string(name) + " must be >= " + std::to_string(low) + ", got " +
                          std::string(py::repr(x)));
  return static_cast<int>(wide);
}

// Caps on a step's iterations. A step runs without the GIL and is interrupted (Ctrl-C) only
// between steps, so its caps bound how long it may run when it never converges: a few
// seconds for a reduced step (line searches and staggers included), and up to a minute for a
// full-space step of the 1,400-node robots (tens of ms per Newton iteration). The defaults
// are 30 to 60 (the reduced model's Newton and stagger caps, the full space's Newton cap).
constexpr int kMaxNewtonCap = 1000;
constexpr int kMaxStaggerCap = 10000;

inline double positive(double v, const char* name) {
  if (!(std::isfinite(v) && v > 0.0)) {
    std::ostringstream msg;
    msg << name << " must be a finite number > 0, got " << v;
    throw py::value_error(msg.str());
  }
  return v;
}

inline double non_negative(double v, const char* name) {
  if (!(std::isfinite(v) && v >= 0.0)) {
    std::ostringstream msg;
    msg << name << " must be a finite number >= 0, got " << v;
    throw py::value_error(msg.str());
  }
  return v;
}

// A per-node mask from None, a boolean array of length n, or an array of node indices.
inline std::vector<char> node_mask(py::handle obj, const char* name, int n) {
  std::vector<char> mask(static_cast<size_t>(n), 0);
  if (obj.is_none()) return mask;
  py::array a = as_array(obj, name);
  if (a.ndim() != 1)
    throw py::value_error(std::string(name) + " has shape " + shape_str(a) +
                          ", expected a 1-D boolean mask or index array");
  // An empty list or array fixes no node, whatever dtype numpy gave it ([] is float64).
  if (a.shape(0) == 0) return mask;
  const char kind = a.dtype().kind();
  if (kind == 'b') {
    if (a.shape(0) != n)
      throw py::value_error(std::string(name) + " is a boolean mask of length " +
                            std::to_string(a.shape(0)) + ", expected " + std::to_string(n));
    auto c = py::array_t<bool, py::array::c_style | py::array::forcecast>::ensure(a);
    for (int i = 0; i < n; ++i) mask[i] = c.data()[i] ? 1 : 0;
  } else if (kind == 'i' || kind == 'u') {
    auto c = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(a);
    for (py::ssize_t k = 0; k < c.size(); ++k) {
      const int64_t i = c.data()[k];
      if (i < 0 || i >= n)
        throw py::value_error(std::string(name) + " contains node index " + std::to_string(i) +
                              " out of range [0, " + std::to_string(n) + ")");
      // A repeated index means nothing as a list of nodes, and is what a 0/1 integer mask
      // (np.array([0, 1, 1, 0])) looks like when read as indices: it would fix nodes 0 and 1
      // instead of the nodes it marks. Refuse it and say how to pass a mask.
      if (mask[i])
        throw py::value_error(std::string(name) + " lists node index " + std::to_string(i) +
                              " more than once; node indices must be distinct (for a 0/1 "
                              "mask, pass a boolean array, e.g. " +
                              name + ".astype(bool))");
      mask[i] = 1;
    }
  } else {
    throw py::type_error(std::string(name) + " must be a boolean mask or integer indices, got dtype " +
                         std::string(py::str(a.dtype())));
  }
  return mask;
}

// An evaluation's result must be finite. Finite input can still overflow inside the material
// model (|F|^2 of coordinates near 1e155 is inf, and inf - inf is NaN): say so rather than hand
// back NaN as if it were physics.
template <typename Derived>
inline void finite_result(const Eigen::DenseBase<Derived>& r, const char* what, const VecX& input,
                          const char* input_name) {
  if (r.allFinite()) return;
  std::ostringstream msg;
  msg << what << " is not finite at " << input_name << " (largest |" << input_name
      << "| = " << (input.size() ? input.cwiseAbs().maxCoeff() : 0.0)
      << "): the material model overflows double precision there";
  throw py::value_error(msg.str());
}

inline void finite_result(double r, const char* what, const VecX& input, const char* input_name) {
  finite_result(Eigen::Matrix<double, 1, 1>::Constant(r), what, input, input_name);
}

template <typename Derived>
inline void finite_result(const Eigen::DenseBase<Derived>& r, const char* what, const VecX& input,
                          const std::string& input_name) {
  finite_result(r, what, input, input_name.c_str());
}

// Node coordinates (or a quantity made of them) computed from reduced coordinates q must be
// finite: finite q can still overflow (coordinates near 1e155 square to inf, a rotation vector
// near 1e300 has no norm), and NaN read as a position or a volume ratio would be silently
// wrong.
template <typename Derived>
inline void finite_coordinates(const Eigen::DenseBase<Derived>& r, const char* what,
                               const VecX& q) {
  if (r.allFinite()) return;
  std::ostringstream msg;
  msg << "the " << what << " at q are not finite (largest |q| = "
      << (q.size() ? q.cwiseAbs().maxCoeff() : 0.0)
      << "): the coordinates overflow double precision there";
  throw py::value_error(msg.str());
}

// (N, 3) float64 numpy array from a 3N vector.
inline py::array_t<double> positions_out(const VecX& x) {
  py::array_t<double> out({static_cast<py::ssize_t>(x.size() / 3), static_cast<py::ssize_t>(3)});
  std::copy(x.data(), x.data() + x.size(), out.mutable_data());
  return out;
}

}  // namespace softrom::validate

namespace pybind11::detail {

template <>
struct type_caster<softrom::validate::RealArgument> {
  PYBIND11_TYPE_CASTER(softrom::validate::RealArgument,
                       io_name("typing.SupportsFloat | typing.SupportsIndex", "float"));
  bool load(handle src, bool convert) {
    make_caster<double> inner;
    if (!inner.load(src, convert)) return false;
    value.value = cast_op<double>(inner);
    value.was_bool = softrom::validate::is_bool(src);
    return true;
  }
  static handle cast(const softrom::validate::RealArgument& v, return_value_policy, handle) {
    return PyFloat_FromDouble(v.value);
  }
};

}  // namespace pybind11::detail
