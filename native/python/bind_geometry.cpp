// Bindings of geometry/: meshes in and out as numpy arrays.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "geometry/cusick.hpp"
#include "geometry/mesh.hpp"
#include "geometry/obj.hpp"

namespace py = pybind11;
using namespace drapelab;

void bind_geometry(py::module_& m) {
  py::class_<TriangleMesh>(m, "TriangleMesh")
      .def(py::init([](const MatrixX3d& positions, const MatrixX3i& faces, std::optional<MatrixX2d> uv,
                       std::optional<MatrixX2d> corner_uv) {
             TriangleMesh mesh;
             mesh.positions = positions;
             mesh.faces = faces;
             mesh.uv = uv ? *uv : MatrixX2d(positions.leftCols<2>());
             if (corner_uv) mesh.corner_uv = *corner_uv;
             validate_mesh(mesh);
             return mesh;
           }),
           py::arg("positions"), py::arg("faces"), py::arg("uv") = py::none(), py::arg("corner_uv") = py::none(),
           "corner_uv: optional (3F, 2) pattern coordinates per face corner (row 3 f + k), for meshes whose seam "
           "vertices lie on two pattern pieces; default: each vertex's uv.")
      .def_readonly("positions", &TriangleMesh::positions)
      .def_readonly("faces", &TriangleMesh::faces)
      .def_readonly("uv", &TriangleMesh::uv)
      .def_readonly("corner_uv", &TriangleMesh::corner_uv)
      .def_property_readonly("num_vertices", &TriangleMesh::num_vertices)
      .def_property_readonly("num_faces", &TriangleMesh::num_faces);
  m.def("read_obj", [](const std::string& path) {
    TriangleMesh mesh = read_obj(path);
    validate_mesh(mesh);
    return mesh;
  }, py::arg("path"));
  m.def("write_obj", [](const std::string& path, const MatrixX3d& positions, const MatrixX3i& faces) {
    write_obj(path, positions, faces);
  }, py::arg("path"), py::arg("positions"), py::arg("faces"));
  m.def("make_cusick_specimen", [](int n) { return make_cusick_specimen(n); }, py::arg("target_vertices"));
  m.def("load_cusick_template", &load_cusick_template, py::arg("level"), py::arg("template_dir"));
  m.def("bending_edges", [](const TriangleMesh& mesh) {
    const auto edges = bending_edges(mesh);
    Eigen::Matrix<int, Eigen::Dynamic, 4, Eigen::RowMajor> out(static_cast<Eigen::Index>(edges.size()), 4);
    for (size_t i = 0; i < edges.size(); ++i)
      out.row(static_cast<Eigen::Index>(i)) << edges[i].a, edges[i].b, edges[i].c, edges[i].d;
    return out;
  }, py::arg("mesh"), "Interior edges as rows (a, b, c, d): edge a-b, c and d opposite.");
}
