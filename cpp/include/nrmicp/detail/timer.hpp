#pragma once
#include <chrono>

namespace nrmicp::detail {

/// Adds the seconds spent in its scope to an accumulator.
class ScopedTimer {
 public:
  explicit ScopedTimer(double& acc) : acc_(acc), t0_(std::chrono::steady_clock::now()) {}
  ~ScopedTimer() { acc_ += seconds_since(t0_); }
  static double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
 private:
  double& acc_;
  std::chrono::steady_clock::time_point t0_;
};

}  // namespace nrmicp::detail
