// The reduced model's settings, bound once: each entry of the table below becomes a validated
// property of `ReducedConfig` and the same-named property of `ReducedModel` (which reads and
// writes the model's own config), and its name is listed in `ReducedConfig.SETTINGS`, which
// the Python front end uses to accept settings. Adding a setting is one entry here plus the
// field in `ReducedConfig` (reduced_model.h).
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <sstream>
#include <limits>
#include <string>
#include <vector>

#include "reduced_model.h"
#include "validate.h"

namespace py = pybind11;
using namespace softrom;
namespace v = softrom::validate;

namespace {

// A setting: how to read it from a config, how to write a Python value into one (validating),
// and its documentation.
struct Setting {
  const char* name;
  py::object (*get)(const ReducedConfig&);
  void (*set)(ReducedConfig&, py::handle);
  const char* doc;
};


Vec3 vec3(py::handle x, const char* name) {
  py::array a = v::as_array(x, name);
  if (a.ndim() != 1 || a.shape(0) != 3)
    throw py::value_error(std::string(name) + " has shape " + v::shape_str(a) +
                          ", expected (3,)");
  const VecX vv = v::real_matrix(a.reshape({py::ssize_t{3}, py::ssize_t{1}}), name, 3, 1);
  return Vec3(vv[0], vv[1], vv[2]);
}

py::object vec3_out(const Vec3& x) { return py::cast(std::vector<double>{x.x(), x.y(), x.z()}); }

const char* contact_name(ContactModel c) {
  switch (c) {
    case ContactModel::Staggered: return "staggered";
    case ContactModel::Penalty: return "penalty";
    default: return "none";
  }
}

#define SOFTROM_POSITIVE(field, doc)                                                      \
  Setting {                                                                               \
    #field, [](const ReducedConfig& c) -> py::object { return py::float_(c.field); },     \
        [](ReducedConfig& c, py::handle x) { c.field = v::positive(v::real(x, #field), #field); }, \
        doc                                                                               \
  }
#define SOFTROM_NON_NEGATIVE(field, doc)                                                  \
  Setting {                                                                               \
    #field, [](const ReducedConfig& c) -> py::object { return py::float_(c.field); },     \
        [](ReducedConfig& c, py::handle x) {                                              \
          c.field = v::non_negative(v::real(x, #field), #field);                             \
        },                                                                                \
        doc                                                                               \
  }
#define SOFTROM_COUNT(field, high, doc)                                                      \
  Setting {                                                                                 \
    #field, [](const ReducedConfig& c) -> py::object { return py::int_(c.field); },         \
        [](ReducedConfig& c, py::handle x) { c.field = v::integer_at_least(x, #field, 1, high); }, \
        doc                                                                                 \
  }

// A named choice's value: a str (numpy's too), not anything whose str() matches.
std::string choice(py::handle x, const char* name) {
  if (!py::isinstance<py::str>(x))
    throw py::type_error(std::string(name) + " must be a str, got " + std::string(py::repr(x)));
  return x.cast<std::string>();
}

const std::vector<Setting>& settings() {
  static const std::vector<Setting> table = {
      {"dt", [](const ReducedConfig& c) -> py::object { return py::float_(c.dt); },
       [](ReducedConfig& c, py::handle x) {
         const double dt = v::positive(v::real(x, "dt"), "dt");
         // (As FEMModel.step: below ~1e-154, 1 / dt^2 overflows, and the penalty ground's
         // step reported a divergence instead of naming dt.)
         if (!std::isfinite(1.0 / (dt * dt))) {
           std::ostringstream msg;
           msg << "dt is too small: 1 / dt^2 overflows, got " << dt;
           throw py::value_error(msg.str());
         }
         c.dt = dt;
       },
       "time step h, s"},
      {"gravity", [](const ReducedConfig& c) { return vec3_out(c.gravity); },
       [](ReducedConfig& c, py::handle x) { c.gravity = vec3(x, "gravity"); },
       "gravitational acceleration (3,), m/s^2"},
      {"contact", [](const ReducedConfig& c) -> py::object { return py::str(contact_name(c.contact)); },
       [](ReducedConfig& c, py::handle x) {
         const std::string s = choice(x, "contact");
         if (s == "staggered") c.contact = ContactModel::Staggered;
         else if (s == "penalty") c.contact = ContactModel::Penalty;
         else if (s == "none") c.contact = ContactModel::None;
         else throw py::value_error("contact must be one of 'staggered', 'penalty', 'none'; got '" + s + "'");
       },
       "'staggered' (default: staggered projection, the accurate model), 'penalty' (an "
       "approximate spring ground, slower than 'staggered' with the fast solver) or 'none'"},
      {"solver", [](const ReducedConfig& c) -> py::object {
         return py::str(c.solver == Solver::Fast ? "fast" : "reference");
       },
       [](ReducedConfig& c, py::handle x) {
         const std::string s = choice(x, "solver");
         if (s == "fast") c.solver = Solver::Fast;
         else if (s == "reference") c.solver = Solver::Reference;
         else throw py::value_error("solver must be 'fast' or 'reference'; got '" + s + "'");
       },
       "'fast' (default: quasi-Newton from the rest stiffness with a line search) or "
       "'reference' (exact Newton every iteration), kept to check the fast path against"},
      SOFTROM_NON_NEGATIVE(friction, "Coulomb coefficient mu"),
      {"ground_height", [](const ReducedConfig& c) -> py::object { return py::float_(c.ground_height); },
       [](ReducedConfig& c, py::handle x) {
         const double z = v::real(x, "ground_height");
         if (!std::isfinite(z)) throw py::value_error("ground_height must be finite");
         // A plane 1e9 m away is no scene; far beyond (1e160 m) the contact solve's bounds,
         // |z| / dt, overflowed and the step fell freely, not reported as diverged.
         constexpr double kMaxGroundHeight = 1e9;
         if (std::abs(z) > kMaxGroundHeight) {
           std::ostringstream msg;
           msg << "ground_height must lie within +-" << kMaxGroundHeight << " m, got " << z;
           throw py::value_error(msg.str());
         }
         c.ground_height = z;
       },
       "height of the ground plane z = ground_height, m"},
      SOFTROM_NON_NEGATIVE(contact_margin,
                           "m: surface nodes predicted closer than this to the ground are "
                           "contact candidates"),
      {"penalty_stiffness",
       [](const ReducedConfig& c) -> py::object { return py::float_(c.penalty_stiffness); },
       [](ReducedConfig& c, py::handle x) {
         const double k = v::non_negative(v::real(x, "penalty_stiffness"), "penalty_stiffness");
         // Far beyond any ground (the defaults are 1e2-1e4 N/m), k times a velocity's
         // round-off outweighs a node's share of the weight: from about 1e22 N/m the normal
         // force was noise, friction vanished, and every step still reported converged.
         constexpr double kMaxPenaltyStiffness = 1e12;
         if (k > kMaxPenaltyStiffness) {
           std::ostringstream msg;
           msg << "penalty_stiffness must be at most " << kMaxPenaltyStiffness
               << " N/m per node, got " << k;
           throw py::value_error(msg.str());
         }
         c.penalty_stiffness = k;
       },
       "N/m per node for contact='penalty', at most 1e12 (0: the body's weight over its "
       "resting nodes per 1 mm of sink, plus 0.25 m_i / dt^2: they sink a little under 1 mm)"},
      SOFTROM_NON_NEGATIVE(fluid_density, "kg/m^3; > 0 turns quadratic surface drag on"),
      SOFTROM_NON_NEGATIVE(drag_coefficient, "C_d of the quadratic drag"),
      SOFTROM_NON_NEGATIVE(damping_alpha, "Rayleigh damping on all reduced coordinates, 1/s"),
      SOFTROM_NON_NEGATIVE(damping_beta, "Rayleigh damping times the rest stiffness K_0, s"),
      SOFTROM_POSITIVE(newton_tolerance,
                       "the implicit solve stops when max |dv| / sqrt(m) < this, m/s"),
      SOFTROM_COUNT(max_newton_iterations, v::kMaxNewtonCap,
                    "cap on implicit-solve iterations per step (at most 1000: a step is "
                    "interrupted only between steps)"),
      SOFTROM_POSITIVE(contact_tolerance,
                       "staggered projection stops when contact-node velocities change less "
                       "than this, m/s"),
      {"friction_smoothing",
       [](const ReducedConfig& c) -> py::object {
         if (c.friction_smoothing > 0.0) return py::float_(c.friction_smoothing);
         return py::none();
       },
       [](ReducedConfig& c, py::handle x) {
         c.friction_smoothing =
             x.is_none() ? 0.0
                         : v::positive(v::real(x, "friction_smoothing"), "friction_smoothing");
       },
       "eps (m/s) of staggered projection's smoothed friction, sqrt(|v_t|^2 + eps^2): "
       "sticking nodes creep at about eps. None (default): contact_tolerance, so that "
       "tightening contact_tolerance alone also sharpens the friction law; set it to keep the "
       "law while the stop tightens"},
      SOFTROM_COUNT(max_stagger_iterations, v::kMaxStaggerCap,
                    "cap on staggered-projection iterations per step (at most 10000: a step "
                    "is interrupted only between steps)"),
      {"stabilization", [](const ReducedConfig& c) -> py::object { return py::float_(c.stabilization); },
       [](ReducedConfig& c, py::handle x) {
         const double b = v::real(x, "stabilization");
         if (!(b > 0.0 && b <= 1.0)) {
           std::ostringstream msg;
           msg << "stabilization must lie in (0, 1], got " << b;
           throw py::value_error(msg.str());
         }
         c.stabilization = b;
       },
       "fraction of a ground penetration removed per step (Baumgarte)"},
      {"direction", [](const ReducedConfig& c) { return vec3_out(c.direction); },
       [](ReducedConfig& c, py::handle x) {
         const Vec3 d = vec3(x, "direction");
         // Scaled by its largest entry first: |d| of a finite d can overflow (1e200) or
         // underflow (1e-170), which would make d / |d| zero or refuse a valid direction.
         const double largest = d.cwiseAbs().maxCoeff();
         if (!(largest > 0)) throw py::value_error("direction must be a non-zero vector");
         const Vec3 unit = d / largest;
         c.direction = unit / unit.norm();
       },
       "unit task direction d; per-step reward d . v_com dt"},
      SOFTROM_POSITIVE(max_speed, "RMS node speed (m/s) above which a step counts as diverged"),
      {"profile", [](const ReducedConfig& c) -> py::object { return py::bool_(c.profile); },
       [](ReducedConfig& c, py::handle x) {
         // True or False (numpy's too), not any object with a truth value
         if (!py::isinstance<py::bool_>(x) &&
             !py::isinstance(x, py::module_::import("numpy").attr("bool_")))
           throw py::type_error("profile must be True or False, got " +
                                std::string(py::repr(x)));
         c.profile = x.cast<bool>();
       },
       "time the parts of each step: step() then reports time_dynamics, time_drag, "
       "time_normal, time_friction (s), and stagger_trace, the staggered projection's course "
       "(benchmarks/trace_staggers.py)"},
      {"frame", [](const ReducedConfig& c) -> py::object {
         return py::str(c.frame == Frame::Floating ? "floating" : "linear");
       },
       [](ReducedConfig& c, py::handle x) {
         const std::string s = choice(x, "frame");
         if (s == "linear") c.frame = Frame::Linear;
         else if (s == "floating") c.frame = Frame::Floating;
         else throw py::value_error("frame must be 'linear' or 'floating'; got '" + s + "'");
       },
       "'linear' (default: x = X + B_r q, rotations linearised) or 'floating' (x = c + R (X + "
       "U z) with an exact rotation: q = (sqrt(m) (c - c_0), rotation vector of R, z), qdot = "
       "(sqrt(m) c', body-frame angular velocity, z'); actuation follows the body, so free "
       "flight keeps the angular momentum; any contact; solver='fast' freezes the Newton "
       "matrix's stiffness at K_0, 'reference' is exact Newton)"},
  };
  return table;
}

}  // namespace

void bind_config(py::module_& m, py::class_<ReducedModel>& model) {
  py::class_<ReducedConfig> cfg(m, "ReducedConfig", R"doc(
Every setting of a reduced model, in one object. `ReducedModel.config` returns a copy and
accepts one; each setting is also a property of the model itself. Values are validated when
set; `ReducedConfig.SETTINGS` lists the names.)doc");
  cfg.def(py::init<>());
  cfg.def(py::init([](py::kwargs kwargs) {
            ReducedConfig c;
            for (auto item : kwargs) {
              const std::string key = py::str(item.first);
              bool found = false;
              for (const Setting& s : settings())
                if (key == s.name) {
                  s.set(c, item.second);
                  found = true;
                }
              if (!found) throw py::type_error("unknown setting '" + key + "'");
            }
            return c;
          }),
          "ReducedConfig(**settings): defaults, then the given settings (validated).");
  py::list names;
  for (const Setting& s : settings()) {
    names.append(s.name);
    const Setting* p = &s;
    cfg.def_property(
        s.name, [p](const ReducedConfig& c) { return p->get(c); },
        [p](ReducedConfig& c, py::handle x) { p->set(c, x); }, s.doc);
    model.def_property(
        s.name, [p](const ReducedModel& r) { return p->get(r.config); },
        [p](ReducedModel& r, py::handle x) { p->set(r.config, x); }, s.doc);
  }
  cfg.attr("SETTINGS") = py::tuple(names);
  cfg.def(
      "validate", [](const ReducedConfig&) {},
      "Raise ValueError if the settings, each valid alone, cannot be stepped together. Every "
      "combination steps today (frame='floating' with the penalty ground since 2026-12-07), so "
      "it returns; it stays so that code calling it keeps working.");
  cfg.def("__repr__", [](const ReducedConfig& c) {
    std::string out = "ReducedConfig(";
    bool first = true;
    for (const Setting& s : settings()) {
      if (!first) out += ", ";
      first = false;
      out += std::string(s.name) + "=" + std::string(py::repr(s.get(c)));
    }
    return out + ")";
  });
  // Pickled (and so copied, and sent to worker processes) as ReducedConfig(**settings), so an
  // unpickled config goes through the same validation as a new one.
  cfg.def("__reduce__", [](py::object self) {
    const ReducedConfig& c = self.cast<const ReducedConfig&>();
    py::dict values;
    for (const Setting& s : settings()) values[s.name] = s.get(c);
    py::object partial = py::module_::import("functools").attr("partial");
    return py::make_tuple(partial(py::type::of(self), **values), py::tuple());
  });
  cfg.def(
      "__eq__",
      // A ReducedConfig argument with is_operator: anything else gets NotImplemented, as
      // Python's own types answer.
      [](const ReducedConfig& a, const ReducedConfig& b) {
        for (const Setting& s : settings())
          if (!s.get(a).equal(s.get(b))) return false;
        return true;
      },
      py::is_operator());
  model.def_property(
      "config", [](const ReducedModel& r) { return r.config; },
      [](ReducedModel& r, const ReducedConfig& c) { r.config = c; },
      "A copy of all settings (ReducedConfig); assign one to change several at once.");
}
