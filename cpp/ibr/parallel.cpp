#include "ibr/parallel.h"

#include <algorithm>
#include <exception>
#include <memory>
#include <mutex>

#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#if defined(__SANITIZE_THREAD__)
#include <sanitizer/tsan_interface.h>
#endif

namespace ibr {
namespace {

// ThreadSanitizer builds (IBR_SANITIZE_THREAD): TBB's scheduler lives in the uninstrumented
// libtbb, so TSan does not see that a loop's tasks start after the caller's writes and end
// before the caller goes on; every reuse of memory the tasks touched (the caller's stack, a
// freed buffer) was then reported as a race (steerable.cpp, the first report of the kernels'
// tests under TSan). The two edges are marked on two sync addresses: `start` released by the
// caller and acquired by each task, `done` released by each task and acquired by the caller.
// Tasks never acquire `done`, so races between tasks are still reported. No code otherwise.
#if defined(__SANITIZE_THREAD__)
inline void TsanAcquire(void* sync) { __tsan_acquire(sync); }
inline void TsanRelease(void* sync) { __tsan_release(sync); }
#else
inline void TsanAcquire(void*) {}
inline void TsanRelease(void*) {}
#endif

std::mutex g_control_mutex;
std::unique_ptr<tbb::global_control> g_control;
int g_num_threads = 0;

// Runs the chunks and rethrows the first exception after all chunks ended.
void RunChunks(std::int64_t num_chunks, const std::function<void(std::int64_t)>& chunk) {
  std::exception_ptr first;
  std::mutex error_mutex;
  char start = 0, done = 0;  // TSan sync addresses (see TsanAcquire)
  TsanRelease(&start);
  tbb::parallel_for(
      tbb::blocked_range<std::int64_t>(0, num_chunks, 1),
      [&](const tbb::blocked_range<std::int64_t>& r) {
        TsanAcquire(&start);
        for (std::int64_t i = r.begin(); i != r.end(); ++i) {
          try {
            chunk(i);
          } catch (...) {
            std::lock_guard<std::mutex> lock(error_mutex);
            if (!first) first = std::current_exception();
          }
        }
        TsanRelease(&done);
      },
      tbb::simple_partitioner());
  TsanAcquire(&done);
  if (first) std::rethrow_exception(first);
}

}  // namespace

void SetNumThreads(int num_threads) {
  std::lock_guard<std::mutex> lock(g_control_mutex);
  g_control.reset();
  g_num_threads = std::max(0, num_threads);
  if (g_num_threads > 0) {
    g_control = std::make_unique<tbb::global_control>(
        tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(g_num_threads));
  }
}

int GetNumThreads() {
  return static_cast<int>(
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
}

void ParallelFor(std::int64_t n, std::int64_t grain,
                 const std::function<void(std::int64_t, std::int64_t)>& fn) {
  if (n <= 0) return;
  grain = std::max<std::int64_t>(1, grain);
  const std::int64_t num_chunks = (n + grain - 1) / grain;
  RunChunks(num_chunks, [&](std::int64_t i) {
    const std::int64_t begin = i * grain;
    fn(begin, std::min(n, begin + grain));
  });
}

void ParallelFor2D(int height, int width, int tile,
                   const std::function<void(int, int, int, int)>& fn) {
  if (height <= 0 || width <= 0) return;
  int tile_w = std::max(8, tile);
  int tile_h = std::max(8, tile);
  // Grain floor: grow tiles (rows first) until each holds enough pixels to be worth a task.
  while (std::int64_t(tile_w) * tile_h < kMinPixelsPerTask &&
         (tile_h < height || tile_w < width)) {
    if (tile_h < height) tile_h *= 2; else tile_w *= 2;
  }
  const int tiles_x = (width + tile_w - 1) / tile_w;
  const int tiles_y = (height + tile_h - 1) / tile_h;
  RunChunks(std::int64_t(tiles_x) * tiles_y, [&](std::int64_t i) {
    const int ty = static_cast<int>(i / tiles_x), tx = static_cast<int>(i % tiles_x);
    const int y0 = ty * tile_h, x0 = tx * tile_w;
    fn(y0, std::min(height, y0 + tile_h), x0, std::min(width, x0 + tile_w));
  });
}

}  // namespace ibr
