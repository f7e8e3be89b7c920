// Threads of the abcgs CPU kernels, independent of PyTorch's intra-op pool.
//
// The training loops run torch with one intra-op thread (abcgs/fit/trainer.py: with other processes on the
// cores, OpenMP workers busy-wait and small ops slow down many times), which used to leave the rasterizer on one
// core too. These helpers run the kernels' own loops on plain std::threads (joined at the end of each loop, so
// nothing spins between calls) with a count set from Python (set_kernel_threads; 0 = every hardware thread).
//
// Determinism: callers give every output element to exactly one worker (tiles own their pixels and their
// intersection rows; per-Gaussian loops write only that Gaussian's entries), so results are bit-identical for
// any thread count.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace abcgs {

inline std::atomic<int>& kernel_threads_setting() {
  static std::atomic<int> value{0};
  return value;
}

// Set the thread count (0 = every hardware thread); returns the previous setting.
inline int64_t set_kernel_threads(int64_t n) {
  return kernel_threads_setting().exchange(static_cast<int>(std::max<int64_t>(0, n)));
}

inline int64_t kernel_threads() {
  const int n = kernel_threads_setting().load();
  if (n > 0) return n;
  return std::max<int64_t>(1, static_cast<int64_t>(std::thread::hardware_concurrency()));
}

// body(worker) for worker in [0, workers): worker 0 on the calling thread, the others on new threads; the
// first exception thrown by any worker is re-thrown after all have joined.
template <typename F>
void run_workers(int64_t workers, const F& body) {
  if (workers <= 1) {
    body(0);
    return;
  }
  std::exception_ptr error;
  std::mutex error_mutex;
  auto guarded = [&](int64_t w) {
    try {
      body(w);
    } catch (...) {
      std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(static_cast<size_t>(workers - 1));
  for (int64_t w = 1; w < workers; ++w) pool.emplace_back(guarded, w);
  guarded(0);
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
}

// fn(begin, end) over [0, n) in contiguous chunks of at least `grain` elements, one chunk per worker.
template <typename F>
void parallel_range(int64_t n, int64_t grain, const F& fn) {
  if (n <= 0) return;
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(kernel_threads(), (n + grain - 1) / grain));
  const int64_t chunk = (n + workers - 1) / workers;
  run_workers(workers, [&](int64_t w) {
    const int64_t begin = w * chunk, end = std::min(n, begin + chunk);
    if (begin < end) fn(begin, end);
  });
}

// Stream compaction of [0, n): keep(i) is tested over contiguous ranges (one per worker) and counted, size(m) is
// called once with the number kept, then emit(i, j) for every kept i with j its rank among them (index order; the
// ranks do not depend on the worker count). keep is called twice per element. Returns m.
template <typename Keep, typename Size, typename Emit>
int64_t parallel_compact(int64_t n, const Keep& keep, const Size& size, const Emit& emit) {
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(kernel_threads(), (n + 65535) / 65536));
  const int64_t chunk = (std::max<int64_t>(n, 0) + workers - 1) / workers;
  std::vector<int64_t> start(workers + 1, 0);
  run_workers(workers, [&](int64_t w) {
    int64_t c = 0;
    for (int64_t i = w * chunk, e = std::min(n, (w + 1) * chunk); i < e; ++i) c += keep(i) ? 1 : 0;
    start[w + 1] = c;
  });
  for (int64_t w = 0; w < workers; ++w) start[w + 1] += start[w];
  size(start[workers]);
  run_workers(workers, [&](int64_t w) {
    int64_t j = start[w];
    for (int64_t i = w * chunk, e = std::min(n, (w + 1) * chunk); i < e; ++i)
      if (keep(i)) emit(i, j++);
  });
  return start[workers];
}

// fn(item) for every item in [0, n), handed out one at a time (dynamic scheduling: tiles differ in cost).
template <typename F>
void parallel_items(int64_t n, const F& fn) {
  if (n <= 0) return;
  std::atomic<int64_t> next{0};
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(kernel_threads(), n));
  run_workers(workers, [&](int64_t) {
    for (int64_t t = next.fetch_add(1); t < n; t = next.fetch_add(1)) fn(t);
  });
}

}  // namespace abcgs
