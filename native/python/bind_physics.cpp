// Bindings of physics/ and solver/: Model, ImplicitEuler (rollout and adjoint), StaticSolver (equilibrium and
// adjoint) and Progress (progress-and-cancel sink). Vectors are flat float64 numpy arrays in the model's
// layout: positions and velocities (3V), parameters (layout size). The facade addon/drapelab/sim.py checks
// shapes, reshapes positions to (V, 3) and names the parameter blocks.
//
// Long calls (forward, backward, solve, adjoint, factorize) release the GIL. A Progress passed to them is
// called back with the GIL re-acquired at every step, and its cancel() (callable from any Python thread)
// makes the running call raise Cancelled at the next step. Each solver object serialises its own calls
// with a mutex (it keeps the state of its last forward/solve for the adjoint), so sharing one between
// Python threads is safe, only not parallel.
#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <memory>
#include <mutex>
#include <optional>

#include "contact/diagnostics.hpp"
#include "geometry/mesh.hpp"
#include "garment/body_friction.hpp"
#include "garment/revolved_body.hpp"
#include "physics/model.hpp"
#include "solver/implicit_euler.hpp"
#include "solver/static_solve.hpp"
#include "util/error.hpp"
#include "util/progress.hpp"
#include "py_progress.hpp"

namespace py = pybind11;
using namespace drapelab;
using drapelab_bindings::progress_sink_of;
using drapelab_bindings::PyProgress;

namespace {

using Vector = Eigen::VectorXd;
using MatrixX4iRow = Eigen::Matrix<int, Eigen::Dynamic, 4, Eigen::RowMajor>;

struct PyImplicitEuler {
  explicit PyImplicitEuler(std::shared_ptr<const Model> m) : model(std::move(m)), solver(*model) {}
  std::shared_ptr<const Model> model;  // kept alive as long as the solver
  ImplicitEuler solver;
  std::mutex mutex;
};

struct PyStaticSolver {
  explicit PyStaticSolver(std::shared_ptr<const Model> m) : model(std::move(m)), solver(*model) {}
  std::shared_ptr<const Model> model;
  StaticSolver solver;
  std::mutex mutex;
};

void check_size(const Vector& v, Eigen::Index n, const char* what) {
  if (v.size() != n)
    throw InputError(std::string(what) + ": expected " + std::to_string(n) + " values, got " + std::to_string(v.size()));
}

void check_finite(const Vector& v, const char* what) {
  if (!v.allFinite()) throw InputError(std::string(what) + ": has non-finite values");
}

py::list layout_list(const ParameterLayout& layout) {
  py::list out;
  for (const auto& b : layout.blocks()) {
    py::dict d;
    d["name"] = b.name;
    d["unit"] = b.unit;
    d["offset"] = b.offset;
    d["size"] = b.size;
    d["entries_per_element"] = b.entries_per_element;
    d["shared"] = b.shared;
    out.append(d);
  }
  return out;
}

// The effect registry as Python objects (physics/effect.hpp).
py::list effect_list() {
  py::list out;
  for (const EffectSpec& e : effect_registry()) {
    py::list params;
    for (const EffectParameter& q : e.parameters) {
      py::dict d;
      d["name"] = q.name;
      d["unit"] = q.unit;
      d["off"] = q.off;
      d["lower"] = q.lower;
      d["upper"] = q.upper;
      d["prior_scale"] = q.prior_scale;
      d["moderate"] = q.moderate;
      d["structural"] = q.structural;
      d["description"] = q.description;
      params.append(d);
    }
    py::dict d;
    d["name"] = e.name;
    d["explanation"] = e.explanation;
    d["signature"] = e.signature;
    d["dynamic_only"] = e.dynamic_only;
    d["parameters"] = params;
    py::dict second;
    for (const auto& [name, value] : e.second_direction) second[py::str(name)] = value;
    d["second_direction"] = second;
    py::list steps;
    for (const auto& name : e.step_parameters) steps.append(py::str(name));
    d["step_parameters"] = steps;
    d["step_diagonals"] = e.step_diagonals;
    d["search_grid_spacing"] = e.search_grid_spacing;
    d["search_grid_reach"] = e.search_grid_reach;
    out.append(d);
  }
  return out;
}

}  // namespace

std::vector<RigidPose> poses_from(const std::vector<Eigen::Matrix4d>& T) {
  std::vector<RigidPose> out;
  for (const auto& t : T) {
    RigidPose p;
    p.R = t.topLeftCorner<3, 3>();
    p.c = t.topRightCorner<3, 1>();
    out.push_back(p);
  }
  return out;
}

void bind_physics(py::module_& m) {
  py::class_<RevolvedBodyContact, std::unique_ptr<RevolvedBodyContact, py::nodelete>>(
      m, "RevolvedBodyContact", "A garment's body as a contact obstacle (garment/revolved_body.hpp).")
      .def("set_poses", [](RevolvedBodyContact& b, const std::vector<Eigen::Matrix4d>& start,
                           const std::vector<Eigen::Matrix4d>& end) { b.set_poses(poses_from(start), poses_from(end)); },
           py::arg("start"), py::arg("end"), "Rigid 4x4 poses per part at the start and end of the next step.")
      .def("clearance", [](const RevolvedBodyContact& b, const Vector& x) { return Vector(b.clearance(x)); },
           py::arg("positions"), "Clearance (m, < 0 inside) of each vertex (flat 3V) at the end pose.")
      .def("edge_clearance", [](const RevolvedBodyContact& b, const Vector& x) { return Vector(b.edge_clearance(x)); },
           py::arg("positions"),
           "Clearance (m, < 0 inside) of each cloth edge (min over its points and the parts; order: `edges`).")
      .def_property_readonly("edges", &RevolvedBodyContact::edges, "The cloth edges (vertex pairs) kept off the body.");
  m.def(
      "contact_report",
      [](const MatrixX3i& faces, const Vector& positions, std::optional<MatrixX3d> obstacle_positions,
         std::optional<MatrixX3i> obstacle_faces, double search_radius, int max_listed) {
        if (faces.rows() == 0) throw InputError("contact_report: no faces");
        if (positions.size() % 3 != 0) throw InputError("contact_report: positions must be 3V values");
        check_finite(positions, "contact_report: positions");
        const int nv = static_cast<int>(positions.size() / 3);
        if (faces.minCoeff() < 0 || faces.maxCoeff() >= nv)
          throw InputError("contact_report: a face names a vertex outside 0.." + std::to_string(nv - 1));
        if (obstacle_positions.has_value() != obstacle_faces.has_value())
          throw InputError("contact_report: give both obstacle_positions and obstacle_faces, or neither");
        if (search_radius < 0 || !std::isfinite(search_radius))
          throw InputError("contact_report: search_radius must be >= 0 m (0: the mean edge length)");
        ObstacleMesh obstacle;
        if (obstacle_positions) {
          obstacle.positions = *obstacle_positions;
          obstacle.faces = *obstacle_faces;
          if (!obstacle.positions.allFinite()) throw InputError("contact_report: obstacle positions are not finite");
          if (obstacle.faces.rows() > 0 &&
              (obstacle.faces.minCoeff() < 0 || obstacle.faces.maxCoeff() >= obstacle.positions.rows()))
            throw InputError("contact_report: an obstacle face names a vertex it does not have");
        }
        ContactReport r;
        {
          py::gil_scoped_release no_gil;
          r = contact_report(faces, positions, obstacle_positions ? &obstacle : nullptr, search_radius, max_listed);
        }
        py::dict d;
        d["min_distance_m"] = r.min_distance_m;
        d["search_radius_m"] = r.search_radius_m;
        d["intersecting_pairs"] = r.intersecting_pairs;
        py::list pairs;
        for (const auto& p : r.first_pairs) pairs.append(py::make_tuple(p[0], p[1]));
        d["first_pairs"] = pairs;
        return d;
      },
      py::arg("faces"), py::arg("positions"), py::arg("obstacle_positions") = py::none(),
      py::arg("obstacle_faces") = py::none(), py::arg("search_radius") = 0.0, py::arg("max_listed") = 8,
      "Contact diagnostics of a state (contact/diagnostics.hpp): {min_distance_m (between non-adjacent "
      "primitives within search_radius, +inf when none is that close), search_radius_m, intersecting_pairs "
      "(triangle pairs sharing no vertex that cross), first_pairs (up to max_listed (face, face); obstacle faces "
      "numbered after the cloth's)}. positions: flat 3V; with an obstacle mesh, cloth-obstacle pairs count too.");
  m.def(
      "effects", effect_list,
      "The effect registry (physics/effect.hpp): a list of {name, explanation, signature, dynamic_only, parameters: "
      "[{name, unit, off, lower, upper, prior_scale, moderate, description, structural}]}, in registration order.");

  py::class_<PyProgress, std::shared_ptr<PyProgress>>(
      m, "Progress",
      "Progress-and-cancel sink for long calls: callback(done, total) is called (GIL held) at every step; "
      "cancel() from any thread makes the running call raise Cancelled at its next step.")
      .def(py::init<py::object>(), py::arg("callback") = py::none())
      .def("cancel", [](PyProgress& p) { p.sink.cancel(); }, "Request cancellation (thread-safe).")
      .def_property_readonly("cancelled", [](const PyProgress& p) { return p.sink.cancelled(); });

  py::class_<Model, std::shared_ptr<Model>>(m, "Model",
                                            "Cloth model: mesh, rest data, masses, terms (stretch, bend, gravity, "
                                            "handle) and the flat parameter layout; see physics/model.hpp.")
      .def(py::init([](const TriangleMesh& mesh, bool heterogeneous, double support_radius, double gravity,
                       double density, double handle_stiffness, const EffectValues& effects,
                       const std::vector<int>& held_vertices, const std::vector<std::array<int, 2>>& seams,
                       double seam_stiffness, double px_per_m) {
             ModelOptions o;
             o.px_per_m = px_per_m;
             o.held_vertices = held_vertices;
             o.seams = seams;
             o.seam_stiffness = seam_stiffness;
             o.effects = effects;
             o.heterogeneous = heterogeneous;
             o.support_radius = support_radius;
             o.gravity = gravity;
             o.density = density;
             o.handle_stiffness = handle_stiffness;
             return std::make_shared<Model>(mesh, o);
           }),
           py::arg("mesh"), py::arg("heterogeneous") = false, py::arg("support_radius") = 0.09,
           py::arg("gravity") = 9.8, py::arg("density") = 0.192, py::arg("handle_stiffness") = 1e3,
           py::arg("effects") = EffectValues{}, py::arg("held_vertices") = std::vector<int>{},
           py::arg("seams") = std::vector<std::array<int, 2>>{}, py::arg("seam_stiffness") = 1e3,
           py::arg("px_per_m") = 720.0)
      .def("add_body_contact",
           [](Model& s, const std::vector<std::tuple<Eigen::Vector3d, std::vector<double>, std::vector<double>>>& parts,
              const Vector& kappa, double activation, bool edges_too, double friction) {
             if (!(friction >= 0 && friction <= 2))
               throw InputError("body contact: friction must be a Coulomb coefficient in [0, 2], got " +
                                std::to_string(friction));
             if (kappa.size() != s.num_vertices())
               throw InputError("body contact: expected one stiffness per vertex (" + std::to_string(s.num_vertices()) +
                                "), got " + std::to_string(kappa.size()));
             std::vector<RevolvedPart> ps;
             for (const auto& [origin, sv, rv] : parts) ps.push_back({origin, sv, rv});
             // Every mesh edge once (the body keeps edges off it as well as vertices).
             std::vector<std::array<int, 2>> edges;
             const auto& F = s.mesh().faces;
             for (int f = 0; f < (edges_too ? F.rows() : 0); ++f)
               for (int c = 0; c < 3; ++c) {
                 const int a = F(f, c), b = F(f, (c + 1) % 3);
                 edges.push_back({std::min(a, b), std::max(a, b)});
               }
             std::sort(edges.begin(), edges.end());
             edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
             auto term = std::make_unique<RevolvedBodyContact>(std::move(ps), kappa, activation, std::move(edges));
             RevolvedBodyContact* body = s.add_term(std::move(term));
             if (friction > 0) s.add_term(std::make_unique<BodyFriction>(*body, s.num_vertices(), friction));
             return body;
           },
           py::arg("parts"), py::arg("kappa"), py::arg("activation"), py::arg("edges") = true,
           py::arg("friction") = 0.0,
           py::return_value_policy::reference_internal,
           "Adds contact with a kinematic body of rigid surfaces of revolution (garment/revolved_body.hpp) for every "
           "cloth vertex and every mesh edge: parts [(origin (3,), s (n,), r (n,))], kappa (V,) barrier stiffness "
           "per vertex [J], activation (m); edges=False: vertices only; friction: Coulomb coefficient with the body "
           "(lagged, garment/body_friction.hpp; 0: none). Returns the term (set_poses, clearance, "
           "edge_clearance); the model owns it.")
      .def("set_handle_anchors", &Model::set_handle_anchors, py::arg("anchors"),
           "Moves the handle's anchors (H x 3, metres, in handle_vertices order): a kinematic attachment.")
      .def_property_readonly("active_effects", &Model::active_effects)
      .def("observe",
           [](const Model& s, const Vector& x, const Vector& p) {
             s.validate_parameters(p);
             return Vector(s.observe(x, p));
           },
           py::arg("positions"), py::arg("parameters"),
           "The positions the silhouette renderer sees (flat 3V): x through the active effects' position "
           "transforms (offset, camera); x itself when none is active.")
      .def("observe_backward",
           [](const Model& s, const Vector& x, const Vector& p, const Vector& gy) {
             s.validate_parameters(p);
             Eigen::VectorXd gx = Eigen::VectorXd::Zero(s.num_dofs()), gp = Eigen::VectorXd::Zero(p.size());
             s.add_observe_vjp(x, p, gy, gx, gp);
             return py::make_tuple(Vector(gx), Vector(gp));
           },
           py::arg("positions"), py::arg("parameters"), py::arg("dL_dobserved"),
           "(dL/dx (3V), dL/dp (the layout's size)) of a loss of the observed positions.")
      .def_property_readonly("has_observation", &Model::has_observation)
      .def_property_readonly("px_per_m", [](const Model& s) { return s.options().px_per_m; })
      .def_property_readonly("num_vertices", &Model::num_vertices)
      .def_property_readonly("num_dofs", &Model::num_dofs)
      .def_property_readonly("num_faces", [](const Model& s) { return s.mesh().num_faces(); })
      .def_property_readonly("num_bending_edges", [](const Model& s) { return static_cast<int>(s.bending_edges().size()); })
      .def_property_readonly("num_parameters", [](const Model& s) { return s.layout().size(); })
      .def_property_readonly("mesh", [](const Model& s) { return s.mesh(); },
                             "The model's mesh (faces oriented counter-clockwise in (u, v)).")
      .def_property_readonly("bending_edges", [](const Model& s) {
        const auto& edges = s.bending_edges();
        MatrixX4iRow out(static_cast<Eigen::Index>(edges.size()), 4);
        for (size_t i = 0; i < edges.size(); ++i)
          out.row(static_cast<Eigen::Index>(i)) << edges[i].a, edges[i].b, edges[i].c, edges[i].d;
        return out;
      }, "(E, 4) rows (a, b, c, d) in the order of the bend block's elements.")
      .def_property_readonly("handle_vertices", &Model::handle_vertices)
      .def_property_readonly("heterogeneous", [](const Model& s) { return s.options().heterogeneous; })
      .def_property_readonly("support_radius", [](const Model& s) { return s.options().support_radius; })
      .def_property_readonly("gravity", [](const Model& s) { return s.options().gravity; })
      .def_property_readonly("layout", [](const Model& s) { return layout_list(s.layout()); },
                             "Parameter blocks: list of dicts {name, unit, offset, size, entries_per_element, shared}.")
      .def("rest_positions", &Model::rest_positions, "Flat (3V) rest positions, metres.")
      .def_property_readonly("area_weights", &Model::area_weights, "Per vertex sum of A_f / 3 (m^2).")
      .def("masses", [](const Model& s, const Vector& p) {
        s.validate_parameters(p);
        return s.masses(p);
      }, py::arg("parameters"), "Lumped vertex masses (kg).")
      .def("default_parameters", [](const Model& s) { return Vector(s.default_parameters()); })
      .def("fill_stretch", [](const Model& s, Vector p, const StretchTable& table) {
        check_size(p, s.layout().size(), "parameters");
        s.fill_stretch(p, table);
        return p;
      }, py::arg("parameters"), py::arg("table"), "A copy of parameters with the (6, 4) table on every face.")
      .def("fill_bend", [](const Model& s, Vector p, const BendTable& table) {
        check_size(p, s.layout().size(), "parameters");
        s.fill_bend(p, table);
        return p;
      }, py::arg("parameters"), py::arg("table"), "A copy of parameters with the (3, 5) table on every bending edge.")
      .def("validate_parameters", &Model::validate_parameters, py::arg("parameters"))
      .def("energy", [](const Model& s, const Vector& x, const Vector& p) {
        check_size(x, s.num_dofs(), "positions");
        check_finite(x, "positions");
        s.validate_parameters(p);
        return s.energy(x, p);
      }, py::arg("positions"), py::arg("parameters"), "Total energy E(x; p) (J).")
      .def("gradient", [](const Model& s, const Vector& x, const Vector& p) {
        check_size(x, s.num_dofs(), "positions");
        check_finite(x, "positions");
        s.validate_parameters(p);
        Vector g = Vector::Zero(x.size());
        s.add_gradient(x, p, g);
        return g;
      }, py::arg("positions"), py::arg("parameters"), "dE/dx (N), flat (3V).");

  py::class_<PyImplicitEuler>(m, "ImplicitEuler", "Implicit Euler rollout and its adjoint; see solver/implicit_euler.hpp.")
      .def(py::init([](std::shared_ptr<Model> model) { return std::make_unique<PyImplicitEuler>(std::move(model)); }),
           py::arg("model"))
      .def(
          "forward",
          [](PyImplicitEuler& s, const Vector& p, double time_step, int steps, double max_speed, bool record,
             std::shared_ptr<PyProgress> progress, std::optional<Vector> x0, std::optional<Vector> v0,
             double factor_memory_mb, double contact_force_tolerance, const std::string& contact_step,
             double contact_direction_tolerance) {
            RolloutOptions o;
            if (contact_step == "newton") o.contact_step = RolloutOptions::ContactStep::kNewton;
            else if (contact_step == "linearised") o.contact_step = RolloutOptions::ContactStep::kLinearised;
            else
              throw InputError("contact_step: expected 'linearised' or 'newton', got '" + contact_step + "'");
            o.contact_force_tolerance = contact_force_tolerance;
            o.contact_direction_tolerance = contact_direction_tolerance;
            o.time_step = time_step;
            o.steps = steps;
            o.max_speed = max_speed;
            o.record = record;
            o.factor_memory_mb = factor_memory_mb;
            py::gil_scoped_release no_gil;
            std::lock_guard<std::mutex> lock(s.mutex);
            return s.solver.forward(p, o, progress_sink_of(progress), x0 ? &*x0 : nullptr, v0 ? &*v0 : nullptr);
          },
          py::arg("parameters"), py::arg("time_step") = 0.05, py::arg("steps") = 100, py::arg("max_speed") = 50.0,
          py::arg("record") = true, py::arg("progress") = nullptr, py::arg("x0") = py::none(),
          py::arg("v0") = py::none(), py::arg("factor_memory_mb") = RolloutOptions{}.factor_memory_mb,
          py::arg("contact_force_tolerance") = RolloutOptions{}.contact_force_tolerance,
          py::arg("contact_step") = "linearised",
          py::arg("contact_direction_tolerance") = RolloutOptions{}.contact_direction_tolerance,
          "Rolls out from (x0, v0) (default: rest, at rest); returns final positions (3V). Factors for the adjoint "
          "are kept up to factor_memory_mb (MB); later steps are refactorised in the backward. With contact terms, "
          "contact_step 'linearised' (default) takes the linearised step with the contact terms, its moves cut by "
          "collision detection (another iteration while a move was cut); 'newton' minimises the incremental "
          "potential until every residual force is below contact_force_tolerance (of each vertex's weight). "
          "contact_direction_tolerance: linearised moves with self-contact couplings are solved by CG to this "
          "relative residual; above 1e-10 only with record=False (an animation that is not differentiated).")
      .def(
          "backward",
          [](PyImplicitEuler& s, const Vector& dL_dx, std::optional<Vector> dL_dv, std::shared_ptr<PyProgress> progress,
             std::optional<std::vector<Vector>> alternatives) {
            RolloutGradient g;
            std::vector<Eigen::VectorXd> alts, alt_grads;
            if (alternatives)
              for (const auto& q : *alternatives) alts.emplace_back(q);
            {
              py::gil_scoped_release no_gil;
              std::lock_guard<std::mutex> lock(s.mutex);
              g = s.solver.backward(dL_dx, dL_dv ? &*dL_dv : nullptr, progress_sink_of(progress),
                                    alternatives ? &alts : nullptr, alternatives ? &alt_grads : nullptr);
            }
            py::dict out;
            out["parameters"] = g.parameters;
            out["positions0"] = g.positions0;
            out["velocities0"] = g.velocities0;
            if (alternatives) {
              py::list a;
              for (const auto& q : alt_grads) a.append(Vector(q));
              out["alternatives"] = a;
            }
            return out;
          },
          py::arg("dL_dx"), py::arg("dL_dv") = py::none(), py::arg("progress") = nullptr,
          py::arg("alternatives") = py::none(),
          "dL/d(parameters, x0, v0) of the last forward (record=True): dict of flat arrays. alternatives: parameter "
          "vectors at which the step map is the same function of the state (a tilt's azimuth at zero angle; the "
          "caller's promise); their dL/dp from the same adjoint under 'alternatives'.")
      .def_property_readonly("positions", [](PyImplicitEuler& s) {
        std::lock_guard<std::mutex> lock(s.mutex);
        return Vector(s.solver.positions());
      })
      .def_property_readonly("velocities", [](PyImplicitEuler& s) {
        std::lock_guard<std::mutex> lock(s.mutex);
        return Vector(s.solver.velocities());
      })
      .def_property_readonly("timing", [](PyImplicitEuler& s) {
        std::lock_guard<std::mutex> lock(s.mutex);
        const auto& t = s.solver.timing();
        py::dict out;
        out["assemble"] = t.assemble;
        out["factorize"] = t.factorize;
        out["solve"] = t.solve;
        out["newton_iterations"] = t.newton_iterations;
        out["factorizations"] = t.factorizations;
        out["inexact_adjoint_steps"] = t.inexact_adjoint_steps;
        out["collision"] = t.collision;
        out["cg_iterations"] = t.cg_iterations;
        out["cut_iterations"] = t.cut_iterations;
        out["backward_solve"] = t.backward_solve;
        out["backward_refactorize"] = t.backward_refactorize;
        out["backward_terms"] = t.backward_terms;
        out["backward_start"] = t.backward_start;
        out["backward_refactorizations"] = t.backward_refactorizations;
        return out;
      }, "Seconds spent in assembly, factorisation and solves during the last forward; with contact (IPC steps) "
         "also the Newton iterations and factorisations, and the steps whose adjoint used a definite substitute; "
         "backward_*: the last backward's split (seconds; refactorisations past the factor budget counted).")
      .def(
          "step_system",
          [](PyImplicitEuler& s, const Vector& x, const Vector& v, const Vector& p, double h) {
            const int n = s.model->num_dofs();
            check_size(x, n, "positions");
            check_size(v, n, "velocities");
            s.model->validate_parameters(p);
            Vector A, b;
            {
              py::gil_scoped_release no_gil;
              s.solver.step_system(x, v, p, h, A, b);
            }
            return py::make_tuple(A, b);
          },
          py::arg("positions"), py::arg("velocities"), py::arg("parameters"), py::arg("time_step"),
          "(A, b) of one step: A = M + h^2 K (upper-triangle values in pattern order), b (3V).")
      .def(
          "factorize",
          [](PyImplicitEuler& s, const Vector& values) {
            check_finite(values, "values");
            py::gil_scoped_release no_gil;
            std::lock_guard<std::mutex> lock(s.mutex);
            check_size(values, s.model->pattern().nnz(), "values");
            return s.solver.linear_solver().factorize(values);
          },
          py::arg("values"), "Numeric CHOLMOD factorisation of a step matrix; False if not positive definite.")
      .def_property_readonly("factor_bytes", [](PyImplicitEuler& s) {
        std::lock_guard<std::mutex> lock(s.mutex);
        return s.solver.linear_solver().factor_bytes();
      });

  py::class_<PyStaticSolver>(m, "StaticSolver", "Static equilibrium (Newton) and its adjoint; see solver/static_solve.hpp.")
      .def(py::init([](std::shared_ptr<Model> model) { return std::make_unique<PyStaticSolver>(std::move(model)); }),
           py::arg("model"))
      .def(
          "solve",
          [](PyStaticSolver& s, const Vector& p, double force_tolerance, int max_iterations,
             std::shared_ptr<PyProgress> progress, std::optional<Vector> x0) {
            StaticOptions o;
            o.force_tolerance = force_tolerance;
            o.max_iterations = max_iterations;
            StaticResult r;
            {
              py::gil_scoped_release no_gil;
              std::lock_guard<std::mutex> lock(s.mutex);
              r = s.solver.solve(p, o, progress_sink_of(progress), x0 ? &*x0 : nullptr);
            }
            py::dict out;
            out["positions"] = r.positions;
            out["iterations"] = r.iterations;
            out["residual"] = r.residual;
            return out;
          },
          py::arg("parameters"), py::arg("force_tolerance") = 1e-6, py::arg("max_iterations") = 200,
          py::arg("progress") = nullptr, py::arg("x0") = py::none(),
          "Equilibrium from x0 (default rest): dict positions (3V), iterations, residual (in vertex weights).")
      .def(
          "adjoint",
          [](PyStaticSolver& s, const Vector& dL_dx) {
            py::gil_scoped_release no_gil;
            std::lock_guard<std::mutex> lock(s.mutex);
            return s.solver.adjoint(dL_dx);
          },
          py::arg("dL_dx"), "dL/dparameters (flat) given dL/dx* (3V) at the last solution.");
}
