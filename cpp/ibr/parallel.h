// The engine's one thread pool: TBB, with a thread limit set once (--threads) and loops
// whose partition depends only on the problem size, never on the thread count, so results
// are identical for any number of threads.
#pragma once
#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>

namespace ibr {

// Limits the threads every later ParallelFor may use (0 = all cores).
void SetNumThreads(int num_threads);
int GetNumThreads();

// Calls fn(begin, end) over [0, n) in chunks of at least `grain` items. Exceptions thrown
// by fn are collected and the first is rethrown after the loop.
void ParallelFor(std::int64_t n, std::int64_t grain,
                 const std::function<void(std::int64_t, std::int64_t)>& fn);

// Calls fn(y0, y1, x0, x1) over an image cut into tiles of tile x tile pixels; tiles are
// made larger when needed so that each task has at least kMinPixelsPerTask pixels.
constexpr std::int64_t kMinPixelsPerTask = 16384;
void ParallelFor2D(int height, int width, int tile,
                   const std::function<void(int, int, int, int)>& fn);

// The smallest index the chunks of a parallel loop report (a kernel's first bad input, say), the
// same whatever the thread count: Report(i) from any thread; Get() is -1 when none was reported.
class FirstIndex {
 public:
  void Report(std::int64_t i) {
    std::int64_t cur = v_.load();
    while (i < cur && !v_.compare_exchange_weak(cur, i)) {
    }
  }
  std::int64_t Get() const {
    const std::int64_t v = v_.load();
    return v == std::numeric_limits<std::int64_t>::max() ? -1 : v;
  }

 private:
  std::atomic<std::int64_t> v_{std::numeric_limits<std::int64_t>::max()};
};

}  // namespace ibr
