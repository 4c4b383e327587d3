// Progress-and-cancel sink taken by every long call (rollouts, solves, fits).
#pragma once
#include <atomic>
#include <functional>
#include <string>

#include "util/error.hpp"

namespace drapelab {

class ProgressSink {
 public:
  // `report(done, total)` may be empty. Returning normally continues; cancellation is via the flag.
  using Callback = std::function<void(int done, int total)>;

  ProgressSink() = default;
  explicit ProgressSink(Callback cb) : callback_(std::move(cb)) {}

  void cancel() { cancelled_.store(true); }
  bool cancelled() const { return cancelled_.load(); }

  // Called at every checkpoint of a long loop: reports, then throws Cancelled if cancel() was called.
  void step(int done, int total) {
    if (callback_) callback_(done, total);
    if (cancelled()) throw Cancelled();
  }

 private:
  Callback callback_;
  std::atomic<bool> cancelled_{false};
};

}  // namespace drapelab
