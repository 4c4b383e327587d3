// Bindings of measure/: images and masks as 2D float64 numpy arrays (rows top to bottom), curves as 1D
// arrays, meshes as (V, 3) / (F, 3) arrays. Options are keyword arguments; the facade
// (addon/drapelab/measure.py) documents them. The GIL is released in every call that touches files or
// loops over images or meshes.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <optional>

#include "measure/calibration.hpp"
#include "measure/drape_measurement.hpp"
#include "measure/image_io.hpp"
#include "measure/manifest.hpp"
#include "measure/mesh_comparison.hpp"
#include "measure/metrics.hpp"
#include "measure/silhouette.hpp"
#include "util/error.hpp"

namespace py = pybind11;
using namespace drapelab;

namespace {

using release = py::call_guard<py::gil_scoped_release>;

Polarity parse_polarity(const std::string& s) {
  if (s == "auto") return Polarity::Auto;
  if (s == "dark_on_light") return Polarity::DarkOnLight;
  if (s == "light_on_dark") return Polarity::LightOnDark;
  throw InputError("polarity must be 'auto', 'dark_on_light' or 'light_on_dark', not '" + s + "'");
}

PixelType parse_pixel_type(const std::string& s) {
  if (s == "uint8") return PixelType::UInt8;
  if (s == "uint16") return PixelType::UInt16;
  if (s == "float") return PixelType::Float;
  throw InputError("pixel_type must be 'uint8', 'uint16' or 'float', not '" + s + "'");
}

HausdorffMode parse_hausdorff(const std::string& s) {
  if (s == "surface") return HausdorffMode::PointToSurface;
  if (s == "vertices") return HausdorffMode::Vertices;
  throw InputError("hausdorff mode must be 'surface' or 'vertices', not '" + s + "'");
}

CameraModel parse_camera(const std::string& s) {
  if (s == "ortho" || s == "orthographic") return CameraModel::Orthographic;
  if (s == "perspective") return CameraModel::Perspective;
  throw InputError("camera must be 'ortho' or 'perspective', not '" + s + "'");
}

Calibration calibration_or_default(const std::optional<Calibration>& c) { return c ? *c : Calibration{}; }

CusickGeometry geometry(double support_radius, double specimen_radius) {
  CusickGeometry g;
  g.support_radius = support_radius;
  g.specimen_radius = specimen_radius;
  return g;
}

SilhouetteOptions silhouette_options(double threshold, const std::string& polarity, bool keep_central_region,
                                     double max_hole_fraction, double min_contrast) {
  SilhouetteOptions o;
  o.threshold = threshold;
  o.polarity = parse_polarity(polarity);
  o.keep_central_region = keep_central_region;
  o.max_hole_fraction = max_hole_fraction;
  o.min_contrast = min_contrast;
  return o;
}

NodeOptions node_options(double smoothing_deg, double min_prominence_m, double min_relative_prominence) {
  NodeOptions o;
  o.smoothing_deg = smoothing_deg;
  o.min_prominence_m = min_prominence_m;
  o.min_relative_prominence = min_relative_prominence;
  return o;
}

#define SILHOUETTE_KWARGS                                                                   \
  py::arg("threshold") = -1.0, py::arg("polarity") = "auto", py::arg("keep_central_region") = true, \
      py::arg("max_hole_fraction") = 0.05, py::arg("min_contrast") = 0.1
#define NODE_KWARGS \
  py::arg("smoothing_deg") = 2.0, py::arg("min_prominence_m") = 0.002, py::arg("min_relative_prominence") = 0.1

}  // namespace

void bind_measure(py::module_& m) {
  py::class_<Calibration>(m, "Calibration", "Orthographic top-view calibration: px_per_m and centre (cx, cy).")
      .def(py::init([](double px_per_m, std::optional<double> cx, std::optional<double> cy) {
             Calibration c;
             c.px_per_m = px_per_m;
             if (cx) c.cx = *cx;
             if (cy) c.cy = *cy;
             return c;
           }),
           py::arg("px_per_m") = kDatasetPxPerM, py::arg("cx") = py::none(), py::arg("cy") = py::none())
      .def_readwrite("px_per_m", &Calibration::px_per_m)
      .def_readwrite("cx", &Calibration::cx)
      .def_readwrite("cy", &Calibration::cy)
      .def_property_readonly("has_centre", &Calibration::has_centre)
      .def("__repr__", [](const Calibration& c) {
        return "Calibration(px_per_m=" + std::to_string(c.px_per_m) + ", cx=" + std::to_string(c.cx) +
               ", cy=" + std::to_string(c.cy) + ")";
      })
      // a value: pickled as its three numbers (the add-on's worker processes receive it)
      .def(py::pickle([](const Calibration& c) { return py::make_tuple(c.px_per_m, c.cx, c.cy); },
                      [](const py::tuple& t) {
                        if (t.size() != 3) throw InputError("Calibration: pickled state must hold 3 numbers");
                        Calibration c;
                        c.px_per_m = t[0].cast<double>();
                        c.cx = t[1].cast<double>();
                        c.cy = t[2].cast<double>();
                        return c;
                      }));
  m.attr("DATASET_PX_PER_M") = kDatasetPxPerM;

  m.def("resolve_calibration", &resolve_calibration, py::arg("calibration"), py::arg("width"), py::arg("height"),
        py::arg("source") = "image");

  // ---- image import / export
  m.def("read_luminance", [](const std::string& path) {
    ImageFileInfo info;
    Image lum;
    {
      py::gil_scoped_release nogil;
      lum = read_luminance(path, &info);
    }
    py::dict d;
    d["width"] = info.width;
    d["height"] = info.height;
    d["channels"] = info.channels;
    d["pixel_type"] = info.pixel_type;
    d["format"] = info.format;
    return py::make_tuple(lum, d);
  }, py::arg("path"), "Luminance in [0, 1] (H, W) and a dict describing the file.");
  m.def("write_image", [](const std::string& path, const Image& image, const std::string& pixel_type, int channels) {
    const PixelType t = parse_pixel_type(pixel_type);
    py::gil_scoped_release nogil;
    write_image(path, image, t, channels);
  }, py::arg("path"), py::arg("image"), py::arg("pixel_type") = "uint8", py::arg("channels") = 1);

  // ---- silhouettes
  py::class_<Silhouette>(m, "Silhouette")
      .def_readonly("mask", &Silhouette::mask)
      .def_readonly("cloth_value", &Silhouette::cloth_value)
      .def_readonly("threshold", &Silhouette::threshold)
      .def_readonly("dark_on_light", &Silhouette::dark_on_light)
      .def_readonly("calibration", &Silhouette::calibration)
      .def_readonly("specks_removed_px", &Silhouette::specks_removed_px)
      .def_readonly("holes_filled_px", &Silhouette::holes_filled_px)
      .def_readonly("source", &Silhouette::source)
      .def_property_readonly("area_px", &Silhouette::area_px);
  m.def("extract_silhouette",
        [](const Image& luminance, std::optional<Calibration> calibration, double threshold, const std::string& polarity,
           bool keep_central_region, double max_hole_fraction, double min_contrast, const std::string& source) {
          const SilhouetteOptions o =
              silhouette_options(threshold, polarity, keep_central_region, max_hole_fraction, min_contrast);
          py::gil_scoped_release nogil;
          return extract_silhouette(luminance, calibration_or_default(calibration), o, source);
        },
        py::arg("luminance"), py::arg("calibration") = py::none(), SILHOUETTE_KWARGS, py::arg("source") = "image");
  m.def("load_silhouette",
        [](const std::string& path, std::optional<Calibration> calibration, double threshold, const std::string& polarity,
           bool keep_central_region, double max_hole_fraction, double min_contrast) {
          const SilhouetteOptions o =
              silhouette_options(threshold, polarity, keep_central_region, max_hole_fraction, min_contrast);
          py::gil_scoped_release nogil;
          return load_silhouette(path, calibration_or_default(calibration), o);
        },
        py::arg("path"), py::arg("calibration") = py::none(), SILHOUETTE_KWARGS);
  m.def("automatic_threshold", &automatic_threshold, py::arg("values"), release());

  // ---- calibration
  m.def("check_cusick_calibration",
        [](const Image& mask, const Calibration& c, const std::string& source, double support_radius,
           double specimen_radius) { check_cusick_calibration(mask, c, source, geometry(support_radius, specimen_radius)); },
        py::arg("mask"), py::arg("calibration"), py::arg("source") = "image", py::arg("support_radius") = 0.09,
        py::arg("specimen_radius") = 0.15, release());
  m.def("calibrate_from_disk", &calibrate_from_disk, py::arg("mask"), py::arg("diameter_m"),
        py::arg("source") = "image", py::arg("max_roundness_error") = 0.1, release());
  m.def("calibrate_from_mesh",
        [](const Image& mask, const MatrixX3d& positions, const MatrixX3i& faces, const std::string& source) {
          MeshCalibrationFit fit;
          {
            py::gil_scoped_release nogil;
            fit = calibrate_from_mesh(mask, positions, faces, source);
          }
          return py::make_tuple(fit.calibration, fit.iou);
        },
        py::arg("mask"), py::arg("positions"), py::arg("faces"), py::arg("source") = "image",
        "(Calibration, iou) fitted so the mesh's orthographic shadow matches the mask.");

  // ---- metrics
  m.def("pixel_mse", &pixel_mse, py::arg("a"), py::arg("b"), release());
  m.def("iou", &iou, py::arg("a"), py::arg("b"), release());
  m.def("shadow_area", &shadow_area, py::arg("mask"), py::arg("px_per_m"), release());
  m.def("drape_coefficient",
        [](const Image& mask, double px_per_m, double support_radius, double specimen_radius) {
          return drape_coefficient(mask, px_per_m, geometry(support_radius, specimen_radius));
        },
        py::arg("mask"), py::arg("px_per_m") = kDatasetPxPerM, py::arg("support_radius") = 0.09,
        py::arg("specimen_radius") = 0.15, release());
  m.def("drape_coefficient_from_area",
        [](double area_m2, double support_radius, double specimen_radius) {
          return drape_coefficient(area_m2, geometry(support_radius, specimen_radius));
        },
        py::arg("shadow_area_m2"), py::arg("support_radius") = 0.09, py::arg("specimen_radius") = 0.15);
  m.def("radius_angle_curve",
        [](const Image& mask, std::optional<Calibration> c, int samples, double step_px) {
          return radius_angle_curve(mask, calibration_or_default(c), samples, step_px);
        },
        py::arg("mask"), py::arg("calibration") = py::none(), py::arg("samples") = 360, py::arg("step_px") = 0.1,
        release());

  py::class_<NodeAnalysis>(m, "NodeAnalysis")
      .def_readonly("count", &NodeAnalysis::count)
      .def_readonly("amplitude_m", &NodeAnalysis::amplitude_m)
      .def_readonly("angles_rad", &NodeAnalysis::angles_rad)
      .def_readonly("prominences_m", &NodeAnalysis::prominences_m)
      .def_readonly("smoothed", &NodeAnalysis::smoothed);
  m.def("analyse_nodes",
        [](const Eigen::VectorXd& r, double s, double p, double rel) { return analyse_nodes(r, node_options(s, p, rel)); },
        py::arg("r_theta"), NODE_KWARGS, release());
  m.def("harmonic_spectrum", &harmonic_spectrum, py::arg("r_theta"), py::arg("count") = 20, release());

  py::class_<RThetaAlignment>(m, "RThetaAlignment")
      .def_readonly("rmse_m", &RThetaAlignment::rmse_m)
      .def_readonly("rotation_rad", &RThetaAlignment::rotation_rad)
      .def_readonly("shift", &RThetaAlignment::shift);
  m.def("r_theta_rmse", &r_theta_rmse, py::arg("measured"), py::arg("model"), release());
  m.def("hausdorff_distance",
        [](const MatrixX3d& pa, const MatrixX3i& fa, const MatrixX3d& pb, const MatrixX3i& fb, const std::string& mode) {
          const HausdorffMode hm = parse_hausdorff(mode);
          py::gil_scoped_release nogil;
          return hausdorff_distance(pa, fa, pb, fb, hm);
        },
        py::arg("positions_a"), py::arg("faces_a"), py::arg("positions_b"), py::arg("faces_b"),
        py::arg("mode") = "surface");
  m.def("point_triangle_distance", &point_triangle_distance, py::arg("p"), py::arg("a"), py::arg("b"), py::arg("c"));

  // ---- aggregate measurements
  py::class_<DrapeMeasurement>(m, "DrapeMeasurement")
      .def_readonly("drape_coefficient", &DrapeMeasurement::drape_coefficient)
      .def_readonly("area_px", &DrapeMeasurement::area_px)
      .def_readonly("px_per_m", &DrapeMeasurement::px_per_m)
      .def_readonly("centre_px", &DrapeMeasurement::centre_px)
      .def_readonly("r_theta_m", &DrapeMeasurement::r_theta_m)
      .def_readonly("harmonics_m", &DrapeMeasurement::harmonics_m)
      .def_readonly("nodes", &DrapeMeasurement::nodes);
  m.def("measure_drape",
        [](const Image& mask, std::optional<Calibration> c, int samples, int harmonics, double s, double p, double rel) {
          DrapeMeasurementOptions o;
          o.r_theta_samples = samples;
          o.harmonics = harmonics;
          o.nodes = node_options(s, p, rel);
          py::gil_scoped_release nogil;
          return measure_drape(mask, calibration_or_default(c), o);
        },
        py::arg("mask"), py::arg("calibration") = py::none(), py::arg("r_theta_samples") = 360,
        py::arg("harmonics") = 20, NODE_KWARGS);

  py::class_<MeshComparison>(m, "MeshComparison")
      .def_readonly("iou", &MeshComparison::iou)
      .def_readonly("mse", &MeshComparison::mse)
      .def_readonly("mesh", &MeshComparison::mesh)
      .def_readonly("image", &MeshComparison::image)
      .def_readonly("r_theta", &MeshComparison::r_theta)
      .def_readonly("model_mask", &MeshComparison::model_mask);
  m.def("compare_mesh_to_silhouette",
        [](const MatrixX3d& positions, const MatrixX3i& faces, const Silhouette& silhouette, const std::string& camera,
           double fov_y, double eye_height) {
          MeshComparisonOptions o;
          o.camera = parse_camera(camera);
          o.fov_y = fov_y;
          o.eye_height = eye_height;
          py::gil_scoped_release nogil;
          return compare_mesh_to_silhouette(positions, faces, silhouette, o);
        },
        py::arg("positions"), py::arg("faces"), py::arg("silhouette"), py::arg("camera") = "ortho",
        py::arg("fov_y") = 0.5, py::arg("eye_height") = 0.7);

  // ---- datasets
  py::class_<ManifestEntry>(m, "ManifestEntry")
      .def_readonly("fabric", &ManifestEntry::fabric)
      .def_readonly("name", &ManifestEntry::name)
      .def_readonly("material", &ManifestEntry::material)
      .def_readonly("weave", &ManifestEntry::weave)
      .def_readonly("density_kg_m2", &ManifestEntry::density_kg_m2)
      .def_readonly("thickness_mm", &ManifestEntry::thickness_mm)
      .def_readonly("sample", &ManifestEntry::sample)
      .def_readonly("capture", &ManifestEntry::capture)
      .def_readonly("silhouette", &ManifestEntry::silhouette)
      .def_readonly("mesh", &ManifestEntry::mesh)
      .def("__repr__", [](const ManifestEntry& e) {
        return "ManifestEntry(fabric=" + std::to_string(e.fabric) + ", sample=" + std::to_string(e.sample) +
               ", capture=" + std::to_string(e.capture) + ", silhouette='" + e.silhouette + "')";
      });
  m.def("read_manifest", py::overload_cast<const std::string&, bool>(&read_manifest), py::arg("path"), py::arg("check_files") = false, release());
}
