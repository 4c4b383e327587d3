// Bindings of render/: cameras, the hard silhouette, the soft rasterizer (forward / backward) and its
// timing helper. Images are 2D float64 numpy arrays (rows top to bottom), positions (V, 3) float64 metres,
// faces (F, 3) int32. The facade addon/drapelab/render.py checks shapes and documents the formulas.
// Forward/backward release the GIL; each SoftRasterizer serialises its own calls with a mutex (it keeps
// the state of the last forward), so sharing one between Python threads is safe, only not parallel.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <mutex>

#include "geometry/mesh.hpp"
#include "render/camera.hpp"
#include "render/rasterizer.hpp"
#include "render/soft_rasterizer.hpp"
#include "util/error.hpp"

namespace py = pybind11;
using namespace drapelab;

namespace {

using release = py::call_guard<py::gil_scoped_release>;
using Points2 = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;

struct PySoftRasterizer {
  PySoftRasterizer(const Camera& camera, const SoftRasterOptions& options) : rasterizer(camera, options) {}
  SoftRasterizer rasterizer;
  std::mutex mutex;
};

Points2 project_points(const Camera& camera, const MatrixX3d& points) {
  Points2 out(points.rows(), 2);
  for (Eigen::Index i = 0; i < points.rows(); ++i) out.row(i) = camera.project(points.row(i).transpose()).transpose();
  return out;
}

// (N, 2, 3) array of d(col, row)/d(x, y, z).
py::array_t<double> camera_jacobians(const Camera& camera, const MatrixX3d& points) {
  py::array_t<double> out({static_cast<py::ssize_t>(points.rows()), py::ssize_t{2}, py::ssize_t{3}});
  auto view = out.mutable_unchecked<3>();
  Eigen::Matrix<double, 2, 3> jacobian;
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    camera.project(points.row(i).transpose(), &jacobian);
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 3; ++b) view(i, a, b) = jacobian(a, b);
  }
  return out;
}

}  // namespace

void bind_render(py::module_& m) {
  py::class_<Camera, std::shared_ptr<Camera>>(m, "Camera",
                                              "Measurement model: 3D points (m) -> image coordinates (col, row) in pixels.")
      .def_property_readonly("width", &Camera::width)
      .def_property_readonly("height", &Camera::height)
      .def_property_readonly("kind", &Camera::kind)
      .def("project", &project_points, py::arg("points"), "(N, 3) points -> (N, 2) image coordinates (col, row).")
      .def("jacobians", &camera_jacobians, py::arg("points"), "(N, 3) points -> (N, 2, 3) d(col, row)/d(x, y, z).")
      .def("in_front", [](const Camera& c, const Eigen::Vector3d& p) { return c.in_front(p); }, py::arg("point"));

  py::class_<OrthographicCamera, Camera, std::shared_ptr<OrthographicCamera>>(
      m, "OrthographicCamera", "col = cx + px_per_m x, row = cy - px_per_m y (top view looking down -z).")
      .def(py::init<double, double, double, int, int>(), py::arg("px_per_m") = 720.0, py::arg("cx") = 128.0,
           py::arg("cy") = 128.0, py::arg("width") = 256, py::arg("height") = 256)
      .def_property_readonly("px_per_m", &OrthographicCamera::px_per_m)
      .def_property_readonly("centre", &OrthographicCamera::centre)
      .def("__repr__", [](const OrthographicCamera& c) {
        return "OrthographicCamera(px_per_m=" + std::to_string(c.px_per_m()) + ", cx=" + std::to_string(c.centre().x()) +
               ", cy=" + std::to_string(c.centre().y()) + ", width=" + std::to_string(c.width()) +
               ", height=" + std::to_string(c.height()) + ")";
      });

  py::class_<PerspectiveCamera, Camera, std::shared_ptr<PerspectiveCamera>>(
      m, "PerspectiveCamera",
      "Eye at (0, 0, eye_height) looking down -z: col = W/2 + f x / (eye_height - z), "
      "row = H/2 - f y / (eye_height - z), f = (H/2) / tan(fov_y/2).")
      .def(py::init<double, double, int, int>(), py::arg("fov_y") = 0.5, py::arg("eye_height") = 0.7,
           py::arg("width") = 256, py::arg("height") = 256)
      .def_property_readonly("fov_y", &PerspectiveCamera::fov_y)
      .def_property_readonly("eye_height", &PerspectiveCamera::eye_height)
      .def_property_readonly("focal_px", &PerspectiveCamera::focal_px)
      .def("__repr__", [](const PerspectiveCamera& c) {
        return "PerspectiveCamera(fov_y=" + std::to_string(c.fov_y()) + ", eye_height=" + std::to_string(c.eye_height()) +
               ", width=" + std::to_string(c.width()) + ", height=" + std::to_string(c.height()) + ")";
      });

  m.def("hard_silhouette", &hard_silhouette, py::arg("camera"), py::arg("positions"), py::arg("faces"), release(),
        "Binary silhouette (H, W): 1 where a pixel centre is covered by a projected triangle.");

  py::class_<PySoftRasterizer>(m, "SoftRasterizer", "Soft silhouette rasterizer; see render/soft_rasterizer.hpp.")
      .def(py::init([](const Camera& camera, double sigma, double epsilon, const std::string& profile) {
             SoftRasterOptions options;
             options.sigma = sigma;
             options.epsilon = epsilon;
             options.profile = soft_profile_from_string(profile);
             return std::make_unique<PySoftRasterizer>(camera, options);
           }),
           py::arg("camera"), py::arg("sigma") = 1.0, py::arg("epsilon") = 1e-8, py::arg("profile") = "gaussian")
      .def(
          "forward",
          [](PySoftRasterizer& self, const MatrixX3d& positions, const MatrixX3i& faces) {
            std::lock_guard<std::mutex> lock(self.mutex);
            return self.rasterizer.forward(positions, faces);
          },
          py::arg("positions"), py::arg("faces"), release())
      .def(
          "backward",
          [](PySoftRasterizer& self, const Image& grad_image) {
            std::lock_guard<std::mutex> lock(self.mutex);
            return self.rasterizer.backward(grad_image);
          },
          py::arg("grad_image"), release())
      .def_property_readonly("sigma", [](const PySoftRasterizer& s) { return s.rasterizer.options().sigma; })
      .def_property_readonly("epsilon", [](const PySoftRasterizer& s) { return s.rasterizer.options().epsilon; })
      .def_property_readonly("profile", [](const PySoftRasterizer& s) { return to_string(s.rasterizer.options().profile); })
      .def_property_readonly("cutoff_radius_px", [](const PySoftRasterizer& s) { return s.rasterizer.cutoff_radius_px(); })
      .def_property_readonly("width", [](const PySoftRasterizer& s) { return s.rasterizer.camera().width(); })
      .def_property_readonly("height", [](const PySoftRasterizer& s) { return s.rasterizer.camera().height(); })
      .def_property_readonly("transmittance", [](PySoftRasterizer& s) {
        std::lock_guard<std::mutex> lock(s.mutex);
        return Image(s.rasterizer.transmittance());
      });

  m.def(
      "time_soft_render",
      [](const MatrixX3d& positions, const MatrixX3i& faces, int repeats, const Camera& camera, double sigma,
         const std::string& profile) {
        TriangleMesh mesh;
        mesh.positions = positions;
        mesh.faces = faces;
        SoftRasterOptions options;
        options.sigma = sigma;
        options.profile = soft_profile_from_string(profile);
        RenderTiming t;
        {
          py::gil_scoped_release no_gil;
          t = time_soft_render(mesh, repeats, camera, options);
        }
        py::dict out;
        out["forward_ms"] = t.forward_ms;
        out["backward_ms"] = t.backward_ms;
        out["repeats"] = t.repeats;
        out["width"] = t.width;
        out["height"] = t.height;
        out["faces"] = t.faces;
        return out;
      },
      py::arg("positions"), py::arg("faces"), py::arg("repeats"), py::arg("camera"), py::arg("sigma") = 1.0,
      py::arg("profile") = "gaussian", "Median forward and backward times (ms) of the soft rasterizer.");
}
