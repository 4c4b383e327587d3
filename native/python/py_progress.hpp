// The Python side of a ProgressSink (shared by the bindings that take a Progress): a callable invoked with the
// GIL held; the native threads call step() without it, cancel() only sets an atomic flag.
#pragma once
#include <pybind11/pybind11.h>

#include <memory>

#include "util/progress.hpp"

namespace drapelab_bindings {

namespace py = pybind11;
using drapelab::ProgressSink;

struct PyProgress {
  explicit PyProgress(py::object cb) : callback(std::move(cb)), sink(make_callback()) {}
  ~PyProgress() {
    py::gil_scoped_acquire gil;  // the callback is released with the GIL held
    callback = py::object();
  }

  ProgressSink::Callback make_callback() {
    if (callback.is_none()) return {};
    return [this](int done, int total) {
      py::gil_scoped_acquire gil;
      callback(done, total);
    };
  }

  py::object callback;
  ProgressSink sink;
};

inline ProgressSink* progress_sink_of(const std::shared_ptr<PyProgress>& p) { return p ? &p->sink : nullptr; }

}  // namespace drapelab_bindings
