// Exceptions of drapelab: every user-facing failure is one of these, with a message that names the problem.
#pragma once
#include <stdexcept>
#include <string>

namespace drapelab {

// Bad input: wrong shapes, NaN, negative stiffness, unreadable files, degenerate meshes.
struct InputError : std::invalid_argument {
  using std::invalid_argument::invalid_argument;
};

// A numerical failure of a solve: divergence, a non-converged Newton solve, a failed factorisation.
struct SolverError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// A long call was cancelled through its ProgressSink.
struct Cancelled : std::runtime_error {
  Cancelled() : std::runtime_error("cancelled") {}
};

}  // namespace drapelab
