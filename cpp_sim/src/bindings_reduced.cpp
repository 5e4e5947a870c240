// Bindings for the reduced model: ReducedState, ReducedModel (its settings: bindings_config.cpp),
// the cubature's training data and the kernels' instruction set (the kernels' and
// least-distance solves' test hooks: bindings_checks.cpp).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <functional>
#include <limits>
#include <sstream>
#include <string>
#include <thread>

#ifdef __linux__
#include <sched.h>
#endif

#include "dense_kernels.h"
#include "fem_model.h"
#include "reduced_model.h"
#include "validate.h"

namespace py = pybind11;
using namespace softrom;
namespace v = softrom::validate;

std::unique_ptr<FEMModel> make_fem(py::handle nodes, py::handle tets, v::RealArgument e,
                                   v::RealArgument nu, v::RealArgument rho);  // bindings.cpp

namespace {

py::array_t<double> vec_out(const VecX& x) {
  py::array_t<double> out(x.size());
  std::copy(x.data(), x.data() + x.size(), out.mutable_data());
  return out;
}

VecX vector_in(py::handle obj, const char* name, Eigen::Index n) {
  py::array a = v::as_array(obj, name);
  if (a.ndim() != 1 || (n >= 0 && a.shape(0) != n)) {
    std::ostringstream msg;
    msg << name << " has shape " << v::shape_str(a) << ", expected ";
    if (n >= 0)
      msg << "(" << n << ",)";
    else
      msg << "a 1-D array";
    throw py::value_error(msg.str());
  }
  return v::real_matrix(a.reshape({a.shape(0), py::ssize_t{1}}), name, n, 1);
}

MatX matrix_in(py::handle obj, const char* name, py::ssize_t rows, py::ssize_t cols) {
  py::array a = v::as_array(obj, name);
  if (a.ndim() != 2 || (rows >= 0 && a.shape(0) != rows) || (cols >= 0 && a.shape(1) != cols)) {
    std::ostringstream msg;
    msg << name << " has shape " << v::shape_str(a) << ", expected (";
    msg << (rows >= 0 ? std::to_string(rows) : std::string("rows")) << ", "
        << (cols >= 0 ? std::to_string(cols) : std::string("cols")) << ")";
    throw py::value_error(msg.str());
  }
  VecX flat = v::real_matrix(a, name, a.shape(0), a.shape(1));
  return Eigen::Map<RowMatX>(flat.data(), a.shape(0), a.shape(1));
}

std::vector<int> index_vector(py::handle obj, const char* name, int bound) {
  py::array a = v::as_array(obj, name);
  if (a.ndim() != 1)
    throw py::value_error(std::string(name) + " has shape " + v::shape_str(a) +
                          ", expected a 1-D array of indices");
  const char kind = a.dtype().kind();
  if (kind != 'i' && kind != 'u')
    throw py::type_error(std::string(name) + " must be an integer array, got dtype " +
                         std::string(py::str(a.dtype())));
  auto c = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(a);
  std::vector<int> out(static_cast<size_t>(c.size()));
  for (py::ssize_t k = 0; k < c.size(); ++k) {
    const int64_t i = c.data()[k];
    if (i < 0 || i >= bound)
      throw py::value_error(std::string(name) + " contains index " + std::to_string(i) +
                            " out of range [0, " + std::to_string(bound) + ")");
    out[k] = static_cast<int>(i);
  }
  return out;
}

// Cores this process may run on (its CPU affinity, which process pools and `taskset` narrow),
// so that the default thread count never oversubscribes a worker process.
int available_cores() {
#ifdef __linux__
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) return std::max(1, CPU_COUNT(&set));
#endif
  return static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

void check_state(const ReducedModel& m, const ReducedState& s) {
  if (s.q.size() != m.dim() || s.qdot.size() != m.dim() ||
      s.impulses.size() != 3 * m.num_surface_nodes()) {
    std::ostringstream msg;
    msg << "state has q of size " << s.q.size() << " and impulses of size " << s.impulses.size()
        << ", expected " << m.dim() << " and " << 3 * m.num_surface_nodes()
        << " for this model";
    throw py::value_error(msg.str());
  }
}

ReducedState make_state(py::handle q, py::handle qdot, py::handle impulses) {
  ReducedState s;
  s.q = vector_in(q, "q", -1);
  s.qdot = vector_in(qdot, "qdot", s.q.size());
  s.impulses = vector_in(impulses, "impulses", -1);
  if (s.q.size() < ReducedModel::kRigid + 1)
    throw py::value_error("q has " + std::to_string(s.q.size()) +
                          " entries, expected M + 6 >= 7 (3 translations, 3 rotations, M >= 1 "
                          "deformation coordinates)");
  if (s.impulses.size() % 3 != 0)
    throw py::value_error("impulses has " + std::to_string(s.impulses.size()) +
                          " entries, not a multiple of 3 (one 3-vector per surface node)");
  return s;
}

std::unique_ptr<ReducedModel> make_reduced(py::handle nodes, py::handle tets, v::RealArgument e,
                                           v::RealArgument nu, v::RealArgument rho,
                                           py::handle basis, py::handle cub_elements,
                                           py::handle cub_weights, py::handle surface_nodes,
                                           py::handle surface_faces) {
  // Reuse the FEM model's validation and rest data.
  const std::unique_ptr<FEMModel> fem_model = make_fem(nodes, tets, e, nu, rho);
  const FEMModel& fem = *fem_model;
  const int n = fem.mesh().num_nodes;
  MatX b = matrix_in(basis, "basis", 3 * n, -1);
  if (b.cols() < ReducedModel::kRigid + 1)
    throw py::value_error("basis has " + std::to_string(b.cols()) +
                          " columns, needs at least 7 (3 translations, 3 rotations, 1 deformation)");
  // B_r^T M B_r = I is what the reduced equations assume (identity reduced mass).
  VecX m3(3 * n);
  for (int i = 0; i < n; ++i) m3.segment<3>(3 * i).setConstant(fem.mass()[i]);
  const double err =
      (b.transpose() * m3.asDiagonal() * b - MatX::Identity(b.cols(), b.cols())).cwiseAbs().maxCoeff();
  if (err > 1e-6) {
    std::ostringstream msg;
    msg << "basis is not mass-orthonormal: max |B^T M B - I| = " << err << " (tolerance 1e-6)";
    throw py::value_error(msg.str());
  }
  const double sm = std::sqrt(fem.mass().sum());
  for (int k = 0; k < 3; ++k)
    for (int i = 0; i < n; ++i)
      for (int a = 0; a < 3; ++a)
        if (std::abs(b(3 * i + a, k) - (a == k ? 1.0 / sm : 0.0)) > 1e-9 / sm) {
          throw py::value_error("basis columns 0..2 must be the rigid translations e_k / sqrt(mass)");
        }
  // Columns 3..5: infinitesimal rotations w x (X - c) about the rest centre of mass c.
  {
    Vec3 c = Vec3::Zero();
    for (int i = 0; i < n; ++i) c += fem.mass()[i] * fem.mesh().rest.segment<3>(3 * i);
    c /= fem.mass().sum();
    MatX raw(3 * n, 3);
    for (int k = 0; k < 3; ++k)
      for (int i = 0; i < n; ++i)
        raw.block<3, 1>(3 * i, k) = Vec3::Unit(k).cross(fem.mesh().rest.segment<3>(3 * i) - c);
    const MatX rot = b.middleCols(3, 3);
    const MatX fit = raw * raw.colPivHouseholderQr().solve(rot);
    const double res = (rot - fit).cwiseAbs().maxCoeff();
    if (!(res <= 1e-8 * rot.cwiseAbs().maxCoeff())) {
      std::ostringstream msg;
      msg << "basis columns 3..5 must be linearised rotations about the centre of mass "
             "(w x (X - c)); largest deviation "
          << res;
      throw py::value_error(msg.str());
    }
  }
  std::vector<int> elems = index_vector(cub_elements, "cubature_elements", fem.mesh().num_tets());
  VecX w = vector_in(cub_weights, "cubature_weights", static_cast<Eigen::Index>(elems.size()));
  if ((w.array() < 0).any()) throw py::value_error("cubature_weights must be >= 0");
  if (!(w.sum() > 0.0))
    throw py::value_error("cubature_weights must have a positive sum (got " +
                          std::to_string(elems.size()) +
                          " elements): without one the body has no elasticity");
  std::vector<int> snodes = index_vector(surface_nodes, "surface_nodes", n);
  {
    std::vector<int> sorted = snodes;
    std::sort(sorted.begin(), sorted.end());
    const auto dup = std::adjacent_find(sorted.begin(), sorted.end());
    if (dup != sorted.end())
      throw py::value_error("surface_nodes lists node " + std::to_string(*dup) +
                            " more than once (it would be two contact points)");
  }
  py::array fa = v::as_array(surface_faces, "surface_faces");
  if (fa.ndim() != 2 || fa.shape(1) != 3)
    throw py::value_error("surface_faces has shape " + v::shape_str(fa) + ", expected (F, 3)");
  std::vector<int> fidx = index_vector(fa.attr("ravel")(), "surface_faces", n);
  std::vector<std::array<int, 3>> faces(fidx.size() / 3);
  for (size_t f = 0; f < faces.size(); ++f) faces[f] = {fidx[3 * f], fidx[3 * f + 1], fidx[3 * f + 2]};
  try {
    return std::make_unique<ReducedModel>(fem.mesh(), fem.material(), fem.mass(), b, elems,
                                          std::vector<double>(w.data(), w.data() + w.size()),
                                          snodes, faces);
  } catch (const std::invalid_argument& ex) {
    throw py::value_error(ex.what());
  }
}

py::array_t<double> controls_in(const ReducedModel& m, py::handle obj, const char* name,
                                int ndim) {
  py::array a = v::as_array(obj, name);
  v::require_real(a, name);
  const int c = m.control_dim();
  if (a.ndim() != ndim || a.shape(ndim - 1) != c) {
    std::ostringstream msg;
    msg << name << " has shape " << v::shape_str(a) << ", expected "
        << (ndim == 3 ? "(B, H, " : "(") << c << (ndim == 1 ? ",)" : ")")
        << " with C = " << c << " the control dimension";
    throw py::value_error(msg.str());
  }
  auto in = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(a);
  // Always a copy: step and rollout read the controls without the GIL, while another
  // Python thread could be writing the caller's array.
  py::array_t<double> out(std::vector<py::ssize_t>(in.shape(), in.shape() + in.ndim()));
  std::copy(in.data(), in.data() + in.size(), out.mutable_data());
  const double* p = out.data();
  for (py::ssize_t i = 0; i < out.size(); ++i)
    if (!std::isfinite(p[i])) {
      std::ostringstream msg;
      msg << name << " contains a non-finite value (" << p[i] << ") at flat index " << i;
      throw py::value_error(msg.str());
    }
  return out;
}

// ReducedModel.step: one step with the GIL released, its StepInfo as a dict (the return type
// is make_tuple's typed tuple, which the stub shows as tuple[ReducedState, dict]).
auto step_binding(const ReducedModel& r, const ReducedState& s, py::handle fc) {
  check_state(r, s);
  ReducedState out = s;
  py::array_t<double> f;
  const double* fp = nullptr;
  if (!fc.is_none()) {
    f = controls_in(r, fc, "f_c", 1);
    fp = f.data();
  } else if (r.control_dim() > 0) {
    throw py::value_error("f_c is required: this model has a control basis with C = " +
                          std::to_string(r.control_dim()));
  }
  StepInfo info;
  const StepInputs in = r.inputs();  // copied while the GIL is held
  {
    py::gil_scoped_release release;
    const ReducedModel::WorkspaceLease ws = r.lend_workspace();
    info = r.step(in, out, fp, *ws);
  }
  py::dict d;
  d["newton_iterations"] = info.newton_iterations;
  d["stiffness_evaluations"] = info.stiffness_evaluations;
  d["stagger_iterations"] = info.stagger_iterations;
  d["contacts"] = info.contacts;
  d["normal_iterations"] = info.normal_iterations;
  d["friction_iterations"] = info.friction_iterations;
  d["active_rows"] = info.active_rows;
  d["converged"] = info.converged;
  d["contact_converged"] = info.contact_converged;
  d["diverged"] = info.diverged;
  if (in.config.profile) {
    d["time_dynamics"] = info.time_dynamics;
    d["time_drag"] = info.time_drag;
    d["time_normal"] = info.time_normal;
    d["time_friction"] = info.time_friction;
    d["stagger_trace"] = info.stagger_trace;
  }
  return py::make_tuple(out, d);
}

// A rollout's start states: one ReducedState (every rollout starts there) or a sequence of b.
std::vector<ReducedState> rollout_starts(const ReducedModel& r, py::handle state, int b) {
  std::vector<ReducedState> starts;
  if (py::isinstance<ReducedState>(state)) {
    starts.push_back(state.cast<ReducedState>());
  } else {
    for (py::handle item : state) {
      if (!py::isinstance<ReducedState>(item))
        throw py::type_error("state must be a ReducedState or a sequence of them");
      starts.push_back(item.cast<ReducedState>());
    }
    if (static_cast<int>(starts.size()) != b)
      throw py::value_error("state is a sequence of " + std::to_string(starts.size()) +
                            " states, expected one per rollout (B = " + std::to_string(b) + ")");
  }
  for (const ReducedState& s : starts) check_state(r, s);
  return starts;
}

// A rollout's thread count: `threads` (an int >= 1, at most b: more would idle), or by
// default the cores this process may run on.
int rollout_threads(py::object threads, int b) {
  if (threads.is_none()) return available_cores();
  // An integer (numpy's too: anything with __index__), not a bool or a float.
  const std::string given = py::str(py::repr(threads));
  if (py::isinstance<py::bool_>(threads) || !PyIndex_Check(threads.ptr()))
    throw py::type_error("threads must be an int or None, got " + given);
  const py::int_ want(py::reinterpret_steal<py::object>(PyNumber_Index(threads.ptr())));
  if (want < py::int_(1)) throw py::value_error("threads must be >= 1, got " + given);
  // (this also keeps the count an int)
  return want > py::int_(b) ? b : want.cast<int>();
}

// ReducedModel.rollout: B rollouts of H steps on the thread pool, the GIL released.
py::dict rollout_binding(const ReducedModel& r, py::handle state, py::handle controls,
                         py::object threads, py::handle observe) {
  py::array_t<double> u = controls_in(r, controls, "controls", 3);
  constexpr py::ssize_t kMaxCount = std::numeric_limits<int>::max();
  if (u.shape(0) < 1 || u.shape(1) < 1 || u.shape(0) > kMaxCount || u.shape(1) > kMaxCount)
    throw py::value_error("controls must have 1 <= B, H <= " + std::to_string(kMaxCount) +
                          ", got B = " + std::to_string(u.shape(0)) +
                          ", H = " + std::to_string(u.shape(1)));
  const int b = static_cast<int>(u.shape(0)), h = static_cast<int>(u.shape(1));
  // The inputs are copied here, while the GIL is held and before any of the caller's code
  // runs (iterating `state`, `threads.__index__`, `observe.__array__`): that code may assign
  // control_basis, and the controls were checked against this C (a C read later strode
  // through the buffer with another width, past its end for a wider one).
  const StepInputs in = r.inputs();
  const std::vector<ReducedState> starts = rollout_starts(r, state, b);
  const int nt = rollout_threads(threads, b);
  const py::ssize_t dim = r.dim(), ni = 3 * r.num_surface_nodes();
  py::array_t<double> rewards({b, h}), q({py::ssize_t{b}, dim}), qd({py::ssize_t{b}, dim}),
      imp({py::ssize_t{b}, ni}), com({py::ssize_t{b}, py::ssize_t{h}, py::ssize_t{3}});
  py::array_t<bool> div(b), conv(b);
  std::vector<unsigned char> flags(b), conv_flags(b);
  py::array_t<int> good(b);
  MatX obs_m;
  py::ssize_t no = 0;
  if (!observe.is_none()) {
    obs_m = matrix_in(observe, "observe", -1, r.dim());
    no = obs_m.rows();
  }
  py::array_t<double> observed({py::ssize_t{b}, py::ssize_t{h}, no});
  ReducedModel::RolloutOutputs out;
  out.rewards = rewards.mutable_data();
  out.final_q = q.mutable_data();
  out.final_qdot = qd.mutable_data();
  out.final_impulses = imp.mutable_data();
  out.diverged = flags.data();
  out.converged = conv_flags.data();
  out.good_steps = good.mutable_data();
  out.com = com.mutable_data();
  out.observe = no ? &obs_m : nullptr;
  out.observed = no ? observed.mutable_data() : nullptr;
  // Ctrl-C: Python only runs signal handlers on the main thread, so only a rollout
  // called from it asks (PyErr_CheckSignals sets the KeyboardInterrupt raised below).
  bool interrupted = false;
  const std::function<bool()> check_signals = [&interrupted] {
    py::gil_scoped_acquire gil;
    interrupted = PyErr_CheckSignals() != 0;
    return interrupted;
  };
  const py::module_ threading = py::module_::import("threading");
  if (threading.attr("current_thread")().is(threading.attr("main_thread")()))
    out.interrupt = &check_signals;
  {
    py::gil_scoped_release release;
    r.rollout(in, starts, u.data(), b, h, nt, out);
  }
  if (interrupted) throw py::error_already_set();
  for (int i = 0; i < b; ++i) {
    div.mutable_data()[i] = flags[i] != 0;
    conv.mutable_data()[i] = conv_flags[i] != 0;
  }
  py::dict d;
  d["rewards"] = rewards;
  d["q"] = q;
  d["qdot"] = qd;
  d["impulses"] = imp;
  d["diverged"] = div;
  d["converged"] = conv;
  d["good_steps"] = good;
  d["com"] = com;
  if (!observe.is_none()) d["observed"] = observed;
  return d;
}

}  // namespace

void bind_config(py::module_& m, py::class_<ReducedModel>& model);
void bind_checks(py::module_& m);  // bindings_checks.cpp

namespace {

void bind_state(py::module_& m) {
  py::class_<ReducedState>(m, "ReducedState", R"doc(
State of a reduced model: q_r and qdot_r (M + 6,) and the contact impulses (3 per surface
node) that warm-start the next contact solve. Copies in, copies out; picklable (by its
constructor's arguments, so an unpickled state is checked as a new one is).)doc")
      .def(py::init(&make_state), py::arg("q"), py::arg("qdot"), py::arg("impulses"))
      .def_property_readonly("q", [](const ReducedState& s) { return vec_out(s.q); })
      .def_property_readonly("qdot", [](const ReducedState& s) { return vec_out(s.qdot); })
      .def_property_readonly("impulses", [](const ReducedState& s) { return vec_out(s.impulses); })
      .def("copy", [](const ReducedState& s) { return ReducedState(s); })
      .def("__copy__", [](const ReducedState& s) { return ReducedState(s); })
      .def("__deepcopy__", [](const ReducedState& s, py::dict) { return ReducedState(s); })
      // __reduce__ rather than py::pickle: pybind11 binds the latter's __setstate__ as a
      // constructor, which it silently ignores on a state already built, so
      // `state.__setstate__(...)` changed nothing. A state is immutable from Python; pickling
      // now calls the constructor, and there is no __setstate__ to misuse.
      .def("__reduce__",
           [](py::object self) {
             const ReducedState& s = self.cast<const ReducedState&>();
             return py::make_tuple(
                 py::type::of(self),
                 py::make_tuple(vec_out(s.q), vec_out(s.qdot), vec_out(s.impulses)));
           })
      .def("__repr__", [](const ReducedState& s) {
        return "ReducedState(dim=" + std::to_string(s.q.size()) + ")";
      });
}

// ReducedModel: construction, its sizes and B_c, and stepping (its settings: bind_config).
py::class_<ReducedModel> bind_model(py::module_& m) {
  py::class_<ReducedModel> model_cls(m, "ReducedModel", R"doc(
Reduced-order soft body in the simulation space B_r (softrom_gym.rom.build_reduced_model is
the Python front end that builds the basis and cubature).

q_r = (3 rigid translations, 3 linearised rotations, M deformation coordinates),
x = X + B_r q_r, B_r^T M B_r = I. Implicit Euler with Newton on the (M + 6)-dimensional system; elastic forces by cubature;
ground contact by staggered projection (default) or penalty; quadratic drag when
fluid_density > 0; actuation f_r = B_c f_c on deformation coordinates only.)doc");
  bind_config(m, model_cls);
  model_cls
      .def(py::init(&make_reduced), py::arg("nodes"), py::arg("tets"), py::arg("youngs_modulus"),
           py::arg("poisson_ratio"), py::arg("density"), py::arg("basis"),
           py::arg("cubature_elements"), py::arg("cubature_weights"), py::arg("surface_nodes"),
           py::arg("surface_faces"))
      .def_property_readonly("dim", &ReducedModel::dim, "M + 6")
      .def_property_readonly("M", &ReducedModel::deformation_dim, "deformation coordinates")
      .def_property_readonly("C", &ReducedModel::control_dim, "control dimension")
      .def_property_readonly("num_nodes", &ReducedModel::num_nodes)
      .def_property_readonly("num_cubature_elements", &ReducedModel::num_cubature_elements)
      .def_property_readonly_static("SOLVERS", [](py::object) { return py::make_tuple("reference", "fast"); })
      .def_property_readonly("total_mass", &ReducedModel::total_mass)
      .def_property_readonly("surface_nodes", &ReducedModel::surface_nodes)
      .def_property(
          "control_basis", [](const ReducedModel& r) { return MatX(r.control_basis()); },
          [](ReducedModel& r, py::handle bc) {
            const MatX b = matrix_in(bc, "control_basis", r.deformation_dim(), -1);
            if (b.cols() > b.rows())
              throw py::value_error("control_basis has " + std::to_string(b.cols()) +
                                    " columns, more than M = " + std::to_string(b.rows()));
            // The control space is a point of the Grassmannian: orthonormal columns. (C = 0, no
            // actuation, has none to check, and maxCoeff of an empty matrix is undefined.)
            const double err =
                b.cols() == 0
                    ? 0.0
                    : (b.transpose() * b - MatX::Identity(b.cols(), b.cols())).cwiseAbs().maxCoeff();
            if (!(err <= 1e-8)) {
              std::ostringstream msg;
              msg << "control_basis is not orthonormal: max |B_c^T B_c - I| = " << err
                  << " (tolerance 1e-8)";
              throw py::value_error(msg.str());
            }
            r.set_control_basis(b);
          },
          "B_c, (M, C), orthonormal: f_r = B_c f_c acts on the deformation coordinates.")
      .def("rest_state", &ReducedModel::rest_state,
           "The undeformed state at rest: q = qdot = 0 (M + 6,), no contact impulses.")
      .def("step", &step_binding,
           py::arg("state"), py::arg("f_c") = py::none(),
           "One implicit step; returns (new_state, info). A diverged step returns the input "
           "state and info['diverged'] = True and does not raise (a state or f_c of the wrong "
           "size raises ValueError).")
      .def("rollout", &rollout_binding,
           py::arg("state"), py::arg("controls"), py::arg("threads") = py::none(),
           py::arg("observe") = py::none(),
           R"doc(B rollouts of H steps from one state (or a sequence of B states), controls (B, H, C).

Returns a dict: rewards (B, H) = d . v_com dt per step, q / qdot (B, M + 6) and impulses
(B, 3 n_surface) of the final states, diverged (B,), converged (B,: every step's Newton and
contact solve reached its tolerance; False for a diverged rollout), good_steps (B,: the
steps solved before the one that diverged; H for a rollout that did not) and com (B, H, 3);
with `observe` (P x (M + 6)), also observed (B, H, P) = observe @ q_r after each step. Rollouts run on
`threads` C++ threads with the GIL released; results do not depend on the thread count. A
diverged rollout keeps its last good state and earns zero reward from then on. Called from
the main thread, Ctrl-C stops it within about 0.1 s (after the step in progress) and raises
KeyboardInterrupt.)doc");
  return model_cls;
}

// What a model computes at given reduced coordinates, and the solvers' test hooks.
void bind_queries(py::class_<ReducedModel>& model_cls) {
  model_cls
      .def(
          "positions",
          [](const ReducedModel& r, py::handle q) {
            const VecX qv = vector_in(q, "q", r.dim());
            const VecX x = r.positions(qv);
            // (Finite q can give NaN: a rotation vector near 1e300 overflows its norm.)
            v::finite_coordinates(x, "positions", qv);
            return v::positions_out(x);
          },
          py::arg("q"), "Node positions (N, 3) of reduced coordinates q (in the model's `frame`).")
      .def(
          "velocities",
          [](const ReducedModel& r, py::handle q, py::handle qdot) {
            const VecX qv = vector_in(q, "q", r.dim());
            const VecX x = r.velocities(qv, vector_in(qdot, "qdot", r.dim()));
            v::finite_coordinates(x, "velocities", qv);
            return v::positions_out(x);
          },
          py::arg("q"), py::arg("qdot"),
          "Node velocities (N, 3) of reduced coordinates q and velocities qdot (in the model's "
          "`frame`: B_r qdot, or u + R (omega x r_i + U_i w)).")
      .def(
          "min_volume_ratio",
          [](const ReducedModel& r, py::handle q) {
            const VecX qv = vector_in(q, "q", r.dim());
            const double j = r.min_volume_ratio(qv);
            // (A NaN determinant would be passed over by the minimum, and overflowing nodes
            // read as "nothing inverted", +inf.)
            v::finite_coordinates(Eigen::Matrix<double, 1, 1>::Constant(j), "volume ratios", qv);
            return j;
          },
          py::arg("q"),
          "min det F over every tetrahedron at reduced coordinates q: the smallest "
          "deformed-to-rest volume ratio J. J <= 0: an element is inverted (a material too soft "
          "for the loads).")
      .def(
          "com", [](const ReducedModel& r, py::handle q) { return vec_out(r.com(vector_in(q, "q", r.dim()))); },
          py::arg("q"), "Centre of mass (3,) of reduced coordinates q.")
      .def(
          "elastic_energy",
          [](const ReducedModel& r, py::handle qd) {
            const VecX q = vector_in(qd, "q_e", r.elastic_dim());
            const double e = r.elastic_energy(q);
            v::finite_result(e, "the reduced elastic energy", q, "q_e");
            return e;
          },
          py::arg("q_e"),
          "Elastic energy E(X + B_e q_e) in J by cubature (sum_k w_k E_k over the cubature "
          "elements k), q_e = q[3:] (M + 3,): "
          "the rotations and deformation coordinates; translations store no energy.")
      .def(
          "elastic_forces",
          [](const ReducedModel& r, py::handle qd) {
            const VecX q = vector_in(qd, "q_e", r.elastic_dim());
            const VecX out = r.elastic_forces(q);
            v::finite_result(out, "the reduced elastic force", q, "q_e");
            return vec_out(out);
          },
          py::arg("q_e"), "Reduced elastic force B_e^T f(X + B_e q_e) (M + 3,) by cubature, q_e = q[3:].")
      .def(
          "_penalty_load",
          [](const ReducedModel& r, py::handle q, py::handle v, py::handle x) {
            const StepInputs in = r.inputs();
            if (in.config.frame != Frame::Linear || in.config.contact != ContactModel::Penalty)
              throw py::value_error("_penalty_load needs frame='linear' and contact='penalty'");
            const VecX qn = vector_in(q, "q", r.dim());
            const VecX vv = vector_in(v, "v", r.dim());
            VecX xv;
            if (!x.is_none()) xv = vector_in(x, "x", r.dim());
            const ReducedModel::WorkspaceLease ws = r.lend_workspace();
            VecX f, cx;
            MatX sym, coupling;
            r.penalty_load_for_tests(in, qn, vv, x.is_none() ? nullptr : &xv, f, sym, coupling,
                                     cx, *ws);
            return py::make_tuple(vec_out(f), sym, coupling,
                                  x.is_none() ? py::object(py::none()) : py::object(vec_out(cx)));
          },
          py::arg("q"), py::arg("v"), py::arg("x") = py::none(),
          "The linear frame's penalty ground force at q + dt v, its Jacobian in v as the solver "
          "forms it (the symmetric part, and the friction's coupling C), and C x as the Newton "
          "step applies it (None without x): for the tests.")
      .def(
          "_floating_residual",
          [](const ReducedModel& r, const ReducedState& s, py::handle fc, py::handle x) {
            check_state(r, s);
            const VecX xv = vector_in(x, "x", r.dim());
            VecX f = VecX::Zero(r.control_dim());
            if (r.control_dim() > 0) f = vector_in(fc, "f_c", r.control_dim());
            const ReducedModel::WorkspaceLease ws = r.lend_workspace();
            MatX res, jac;
            r.floating_residual_for_tests(r.inputs(), s, f, xv, res, jac, *ws);
            return py::make_tuple(vec_out(res.col(0)), jac);
          },
          py::arg("state"), py::arg("f_c"), py::arg("x"),
          "The floating frame's implicit-Euler residual at x = (u', omega', w') from `state`, and "
          "its Jacobian (for the tests' finite-difference check).")
      .def(
          "_elastic_energy_fast",
          [](const ReducedModel& r, py::handle qd) {
            return r.elastic_energy_fast(vector_in(qd, "q_e", r.elastic_dim()));
          },
          py::arg("q_e"), "The cubature energy as the fast solver's line search computes it (for its tests).")
      .def(
          "elastic_stiffness",
          [](const ReducedModel& r, py::handle qd, bool project) {
            const VecX q = vector_in(qd, "q_e", r.elastic_dim());
            MatX k = r.elastic_stiffness(q, project);
            v::finite_result(k, "the reduced stiffness", q, "q_e");
            return k;
          },
          py::arg("q_e"), py::arg("project") = false,
          "Reduced stiffness -d(elastic_forces)/dq_e = sum_k w_k U_k^T H_k U_k (M + 3, M + 3) by "
          "cubature, H_k element k's energy Hessian. project=True clamps each H_k to be PSD "
          "first (the implicit step does not: where its Newton matrix is not positive definite "
          "it clamps the summed stiffness instead).");
}

}  // namespace

void bind_reduced(py::module_& m) {
  bind_state(m);
  py::class_<ReducedModel> model_cls = bind_model(m);
  bind_queries(model_cls);

  m.def(
      "reduced_element_forces",
      [](const FEMModel& fem, py::handle basis, py::handle poses) {
        const int n = fem.mesh().num_nodes;
        MatX b = matrix_in(basis, "basis", 3 * n, -1);
        MatX p = matrix_in(poses, "poses", -1, b.cols());
        const int nt = fem.mesh().num_tets();
        const Eigen::Index md = b.cols();
        py::array_t<double> out({static_cast<py::ssize_t>(p.rows()), static_cast<py::ssize_t>(nt),
                                 static_cast<py::ssize_t>(md)});
        double* o = out.mutable_data();
        {
          py::gil_scoped_release release;
          for (Eigen::Index s = 0; s < p.rows(); ++s) {
            const VecX x = fem.mesh().rest + b * p.row(s).transpose();
            for (int e = 0; e < nt; ++e) {
              const Mat3 f = fem.mesh().deformation_gradient(e, x);
              const Mat3 pk = fem.material().pk1(f);
              const VecX g = -fem.mesh().volume[e] *
                             ((dfdx(fem.mesh().dm_inv[e]) * element_rows(fem.mesh().tets[e], b))
                                  .transpose() *
                              Eigen::Map<const Vec9>(pk.data()));
              std::copy(g.data(), g.data() + md, o + (s * nt + e) * md);
            }
          }
        }
        for (Eigen::Index s = 0; s < p.rows(); ++s)
          v::finite_result(Eigen::Map<const VecX>(o + s * nt * md, nt * md),
                           "the element forces", p.row(s).transpose(), "poses[" +
                           std::to_string(s) + "]");
        return out;
      },
      py::arg("fem"), py::arg("basis"), py::arg("poses"),
      "Per-element reduced elastic forces -V_e G_e^T vec P(F_e) (P, T, K) at poses (P, K) of "
      "a basis (3N, K), the cubature's B_e (rotations and deformation, K = M + 3): the "
      "training data for cubature.");

  m.def(
      "kernel_instruction_set", [] { return std::string(kernels::instruction_set()); },
      "The instruction set of the fast solver's dense kernels (cubature force and stiffness, "
      "contact products) in this process: 'x86-64-v3' (AVX2 + FMA, on an x86-64 CPU that has "
      "it, in builds by GCC 12 or later) or 'baseline'. The set is chosen once per process, "
      "at the kernels' first use (building a model, or a call of this function); set the "
      "environment variable SOFTROM_KERNELS=baseline before that to use the baseline: the two "
      "round differently (fused multiply-adds), so chaotic trajectories computed with the two "
      "part at round-off level.");

  bind_checks(m);
}
