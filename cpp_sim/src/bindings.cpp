// pybind11 module `cpp_sim._core`: a validating binding layer over the unchecked C++ core.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <utility>

#include "fem_model.h"
#include "validate.h"

namespace py = pybind11;
using namespace softrom;
namespace v = softrom::validate;

// FEMModel(nodes, tets, E, nu, rho), validated: the binding's constructor, and the reduced
// model's (bindings_reduced.cpp), which builds its mesh and masses through it.
std::unique_ptr<FEMModel> make_fem(py::handle nodes, py::handle tets, v::RealArgument e,
                                   v::RealArgument nu, v::RealArgument rho) {
  const double youngs_modulus = e.get("youngs_modulus");
  const double poisson_ratio = nu.get("poisson_ratio");
  const double density = rho.get("density");
  VecX x = v::real_matrix(nodes, "nodes", -1, 3);
  if (x.size() < 12) throw py::value_error("nodes must hold at least 4 nodes");
  std::vector<Tet> t = v::tet_array(tets, "tets");
  v::positive(youngs_modulus, "youngs_modulus");
  if (!(poisson_ratio > -1.0 && poisson_ratio < 0.5)) {
    std::ostringstream msg;
    msg << "poisson_ratio must lie in (-1, 0.5), got " << poisson_ratio;
    throw py::value_error(msg.str());
  }
  v::positive(density, "density");
  try {
    return std::make_unique<FEMModel>(x, std::move(t), youngs_modulus, poisson_ratio, density);
  } catch (const std::invalid_argument& e) {
    throw py::value_error(e.what());
  }
}

namespace {

py::object to_csr(const SpMat& k) {
  // K is symmetric, so its column-compressed arrays are also its row-compressed ones.
  const py::ssize_t nnz = k.nonZeros();
  py::array_t<double> data(nnz);
  py::array_t<int32_t> indices(nnz);
  py::array_t<int32_t> indptr(k.outerSize() + 1);
  std::copy(k.valuePtr(), k.valuePtr() + nnz, data.mutable_data());
  std::copy(k.innerIndexPtr(), k.innerIndexPtr() + nnz, indices.mutable_data());
  std::copy(k.outerIndexPtr(), k.outerIndexPtr() + k.outerSize() + 1, indptr.mutable_data());
  py::object csr = py::module_::import("scipy.sparse").attr("csr_matrix");
  return csr(py::make_tuple(data, indices, indptr), py::arg("shape") = py::make_tuple(k.rows(), k.cols()));
}

constexpr std::pair<FEMSolver, const char*> kSolverNames[] = {
    {FEMSolver::kSupernodalLLT, "supernodal_llt"},
    {FEMSolver::kSimplicialLLT, "simplicial_llt"},
    {FEMSolver::kSimplicialLDLT, "simplicial_ldlt"},
    {FEMSolver::kReference, "reference"},
};

std::string solver_name(FEMSolver kind) {
  for (const auto& [k, name] : kSolverNames)
    if (k == kind) return name;
  return "unknown";
}

FEMSolver solver_from_name(const std::string& name) {
  for (const auto& [k, n] : kSolverNames)
    if (name == n) return k;
  std::ostringstream msg;
  msg << "solver must be one of";
  const char* sep = " ";
  for (const auto& kn : kSolverNames) {
    msg << sep << "'" << kn.second << "'";
    sep = ", ";
  }
  msg << ", got '" << name << "'";
  throw py::value_error(msg.str());
}

}  // namespace

void bind_reduced(py::module_& m);

PYBIND11_MODULE(_core, m) {
  m.doc() = "softrom C++ simulation core (FEM, reduced model, contact, batched rollouts).";

  py::class_<FEMModel>(m, "FEMModel", R"doc(
Full-space finite-element model of a soft body.

Linear tetrahedra with the stable Neo-Hookean material (Smith et al. 2018)

    Psi(F) = mu/2 (I_C - 3) - mu (J - 1) + lambda/2 (J - 1)^2,  lambda = lambda_Lame + mu,

which reduces to linear elasticity (E, nu) at small strain and stays restoring under
inversion. Lumped mass, gravity (default (0, 0, -9.81) m/s^2, z up), Rayleigh damping
D = damping_alpha M + damping_beta K(x_n). SI units throughout; positions are (N, 3) arrays.

Parameters
----------
nodes : (N, 3) array of float
    Rest positions in metres.
tets : (T, 4) array of int
    Node indices of each tetrahedron, positively oriented (positive rest volume).
youngs_modulus : float
    E in Pa, > 0.
poisson_ratio : float
    nu, in (-1, 0.5).
density : float
    rho in kg/m^3, > 0.
)doc")
      .def(py::init(&make_fem), py::arg("nodes"), py::arg("tets"), py::arg("youngs_modulus"),
           py::arg("poisson_ratio"), py::arg("density"))
      .def_property_readonly("num_nodes", [](const FEMModel& f) { return f.mesh().num_nodes; })
      .def_property_readonly("num_tets", [](const FEMModel& f) { return f.mesh().num_tets(); })
      .def_property_readonly(
          "mass",
          [](const FEMModel& f) {
            py::array_t<double> out(f.mass().size());
            std::copy(f.mass().data(), f.mass().data() + f.mass().size(), out.mutable_data());
            return out;
          },
          "Lumped mass per node (N,), kg.")
      .def_property_readonly(
          "volumes",
          [](const FEMModel& f) {
            py::array_t<double> out(f.mesh().num_tets());
            std::copy(f.mesh().volume.begin(), f.mesh().volume.end(), out.mutable_data());
            return out;
          },
          "Rest volume per tetrahedron (T,), m^3.")
      .def_property_readonly("volume", [](const FEMModel& f) { return f.mesh().total_volume(); },
                             "Total rest volume, m^3.")
      .def_property_readonly("rest_positions",
                             [](const FEMModel& f) { return v::positions_out(f.mesh().rest); })
      .def_property_readonly("youngs_modulus", &FEMModel::youngs_modulus)
      .def_property_readonly("poisson_ratio", &FEMModel::poisson_ratio)
      .def_property_readonly("density", &FEMModel::density)
      .def_property(
          "gravity", [](const FEMModel& f) { return std::vector<double>{f.gravity.x(), f.gravity.y(), f.gravity.z()}; },
          [](FEMModel& f, py::handle g) {
            py::array a = v::as_array(g, "gravity");
            if (a.ndim() != 1 || a.shape(0) != 3)
              throw py::value_error("gravity has shape " + v::shape_str(a) + ", expected (3,)");
            const VecX gv =
                v::real_matrix(a.reshape({py::ssize_t{1}, py::ssize_t{3}}), "gravity", 1, 3);
            std::lock_guard<std::mutex> lock(f.mutex());
            f.gravity = gv;
          },
          "Gravitational acceleration (3,), m/s^2.")
      .def_property(
          "damping_alpha", [](const FEMModel& f) { return f.damping_alpha; },
          [](FEMModel& f, py::handle x) {
            const double a = v::non_negative(v::real(x, "damping_alpha"), "damping_alpha");
            std::lock_guard<std::mutex> lock(f.mutex());
            f.damping_alpha = a;
          },
          "Mass-proportional Rayleigh damping, 1/s (default 0: it would also damp free flight).")
      .def_property(
          "damping_beta", [](const FEMModel& f) { return f.damping_beta; },
          [](FEMModel& f, py::handle x) {
            const double b = v::non_negative(v::real(x, "damping_beta"), "damping_beta");
            std::lock_guard<std::mutex> lock(f.mutex());
            f.damping_beta = b;
          },
          "Stiffness-proportional Rayleigh damping, s (default 0.005).")
      .def_property(
          "newton_tolerance", [](const FEMModel& f) { return f.newton_tolerance; },
          [](FEMModel& f, py::handle x) {
            const double t = v::positive(v::real(x, "newton_tolerance"), "newton_tolerance");
            std::lock_guard<std::mutex> lock(f.mutex());
            f.newton_tolerance = t;
          },
          "Newton stops when max |dx| / dt falls below this, m/s.")
      .def_property(
          "max_newton_iterations", [](const FEMModel& f) { return f.max_newton_iterations; },
          [](FEMModel& f, py::handle x) {
            const int n = v::integer_at_least(x, "max_newton_iterations", 1, v::kMaxNewtonCap);
            std::lock_guard<std::mutex> lock(f.mutex());
            f.max_newton_iterations = n;
          },
          "Cap on Newton iterations per step (at most 1000: a step is interrupted only between "
          "steps).")
      .def_property(
          "solver", [](const FEMModel& f) { return solver_name(f.solver()); },
          [](FEMModel& f, py::handle x) {
            if (!py::isinstance<py::str>(x))
              throw py::type_error("solver must be a string, got " + std::string(py::repr(x)));
            const FEMSolver kind = solver_from_name(x.cast<std::string>());
            std::lock_guard<std::mutex> lock(f.mutex());
            f.set_solver(kind);
          },
          "How step() solves its Newton systems. 'supernodal_llt' (default), "
          "'simplicial_llt' and 'simplicial_ldlt' share the fast step (closed-form element "
          "projection, in-place assembly on a pre-permuted pattern, symbolic analysis once, no "
          "factorisation once a bound proves convergence) and differ in the sparse Cholesky; "
          "'reference' is the original step, kept to measure against. All converge to the same "
          "implicit-Euler solution under newton_tolerance.")
      .def(
          "energy",
          [](const FEMModel& f, py::handle x) {
            const VecX xv = v::real_matrix(x, "x", f.mesh().num_nodes, 3);
            const double e = f.energy(xv);
            v::finite_result(e, "the elastic energy", xv, "x");
            return e;
          },
          py::arg("x"),
          "Elastic potential energy E(x) in J for positions x (N, 3). Raises ValueError where "
          "positions so large that the material model overflows make it non-finite.")
      .def(
          "forces",
          [](const FEMModel& f, py::handle x) {
            const VecX xv = v::real_matrix(x, "x", f.mesh().num_nodes, 3);
            const VecX out = f.forces(xv);
            v::finite_result(out, "the elastic force", xv, "x");
            return v::positions_out(out);
          },
          py::arg("x"), "Internal elastic forces -dE/dx (N, 3) in N.")
      .def(
          "stiffness",
          [](const FEMModel& f, py::handle x, bool project) {
            const VecX xv = v::real_matrix(x, "x", f.mesh().num_nodes, 3);
            const SpMat k = f.stiffness(xv, project);
            v::finite_result(Eigen::Map<const VecX>(k.valuePtr(), k.nonZeros()), "the stiffness",
                             xv, "x");
            return to_csr(k);
          },
          py::arg("x"), py::arg("project") = false,
          "Stiffness K = d(-forces)/dx as a scipy.sparse CSR (3N, 3N) matrix; row 3i+k is "
          "node i, axis k. project=True clamps each element's Hessian to be PSD, as step() does "
          "(a 9x9 eigensolver for solver='reference', the closed-form eigensystem otherwise).")
      .def(
          "step",
          [](FEMModel& f, py::handle x, py::handle vel, py::handle dt_in, py::handle fixed) {
            const int n = f.mesh().num_nodes;
            VecX xv = v::real_matrix(x, "x", n, 3);
            VecX vv = v::real_matrix(vel, "v", n, 3);
            // A real number, not a bool (dt=True ran a 1-s step), and one whose 1 / dt^2 (the
            // Newton matrix's mass term) is finite: below ~1e-154 it overflowed, and the step
            // failed as "diverged" instead of naming dt.
            const double dt = v::positive(v::real(dt_in, "dt"), "dt");
            if (!std::isfinite(1.0 / (dt * dt))) {
              std::ostringstream msg;
              msg << "dt is too small: 1 / dt^2 overflows, got " << dt;
              throw py::value_error(msg.str());
            }
            std::vector<char> mask = v::node_mask(fixed, "fixed", n);
            VecX xo, vo;
            {
              // The GIL first, then the model's lock: a thread waiting for the lock holds
              // no GIL, so steps of one model from several threads take turns.
              py::gil_scoped_release release;
              std::lock_guard<std::mutex> lock(f.mutex());
              f.step(xv, vv, dt, mask, xo, vo);
            }
            return py::make_tuple(v::positions_out(xo), v::positions_out(vo));
          },
          py::arg("x"), py::arg("v"), py::arg("dt"), py::arg("fixed") = py::none(),
          R"doc(One implicit Euler step; returns (x_new, v_new), each (N, 3).

Newton's method on the incremental potential with a backtracking line search and a sparse
Cholesky solve (see ``solver``). ``fixed`` (boolean mask (N,) or distinct node indices; empty fixes
none) clamps nodes in place.
Raises RuntimeError if the step diverges.)doc")
      .def_property_readonly(
          "last_step_stats",
          [](const FEMModel& f) {
            StepStats s;
            {
              std::lock_guard<std::mutex> lock(f.mutex());
              s = f.last_step_stats();
            }
            py::dict d;
            d["iterations"] = s.iterations;
            d["step_norm"] = s.step_norm;
            d["converged"] = s.converged;
            d["factorizations"] = s.factorizations;
            d["energy_evaluations"] = s.energy_evaluations;
            d["assemble_s"] = s.assemble_s;
            d["gradient_s"] = s.gradient_s;
            d["factorize_s"] = s.factorize_s;
            d["solve_s"] = s.solve_s;
            d["line_search_s"] = s.line_search_s;
            return d;
          },
          "Newton iterations, factorisations and line-search energy evaluations, final max "
          "|dx|/dt, convergence flag and wall seconds per phase (assemble_s, gradient_s, "
          "factorize_s, solve_s, line_search_s) of the last step.");

  bind_reduced(m);
}
