// The compiled module `drapelab_native`: thin bindings, one file per native module.
// Users never import it directly; the facade in addon/drapelab wraps it with shape checks.
#include <pybind11/pybind11.h>

#include "util/error.hpp"

namespace py = pybind11;

void bind_geometry(py::module_& m);
void bind_physics(py::module_& m);
void bind_render(py::module_& m);
void bind_measure(py::module_& m);
void bind_infer(py::module_& m);

PYBIND11_MODULE(drapelab_native, m) {
  m.doc() = "drapelab native core (C++): geometry, physics, solvers, renderer, measurement, inference";
  m.attr("__version__") = DRAPELAB_VERSION;
  py::register_exception<drapelab::InputError>(m, "InputError", PyExc_ValueError);
  py::register_exception<drapelab::SolverError>(m, "SolverError", PyExc_RuntimeError);
  py::register_exception<drapelab::Cancelled>(m, "Cancelled", PyExc_KeyboardInterrupt);
  bind_geometry(m);
  bind_physics(m);
  bind_render(m);
  bind_measure(m);
  bind_infer(m);
}
