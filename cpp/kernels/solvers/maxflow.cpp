// Grid Boykov-Kolmogorov max-flow (see maxflow.h). The structure follows Kolmogorov's
// reference implementation (maxflow-v3.01, the library PyMaxflow wraps): FIFO active queue
// with the "current node" kept across augmentations, timestamps + distances to the terminal
// for the origin test of orphans, orphans processed front-first.
#include "kernels/solvers/maxflow.h"

#include <algorithm>
#include <vector>

namespace ibr {
namespace {

// Parent codes: 0..3 = the direction of the arc to the parent, then the special values.
constexpr std::uint8_t kTerminal = 4;
constexpr std::uint8_t kOrphan = 5;
constexpr std::uint8_t kFree = 6;  // no parent: the node belongs to no tree
constexpr std::int32_t kNotActive = -1;
constexpr int kInfiniteDist = 1 << 30;

template <typename Cap>
class GridBK {
 public:
  GridBK(int h, int w) : h_(h), w_(w), n_(std::int64_t(h) * w) {
    cap_.assign(4 * n_, Cap(0));
    tr_cap_.assign(n_, Cap(0));
    parent_.assign(n_, kFree);
    is_sink_.assign(n_, 0);
    next_.assign(n_, kNotActive);
    ts_.assign(n_, 0);
    dist_.assign(n_, 0);
    exists_.assign(n_, 0);
    off_[0] = 1;
    off_[1] = -1;
    off_[2] = w;
    off_[3] = -w;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        std::uint8_t m = 0;
        if (x + 1 < w) m |= 1;
        if (x > 0) m |= 2;
        if (y + 1 < h) m |= 4;
        if (y > 0) m |= 8;
        exists_[std::int64_t(y) * w + x] = m;
      }
    }
  }

  Cap Run(const Cap* src, const Cap* snk, const Cap* right, const Cap* down, std::uint8_t* sink_side) {
    Cap flow = 0;
    for (int y = 0; y < h_; ++y) {
      for (int x = 0; x < w_; ++x) {
        const std::int64_t n = std::int64_t(y) * w_ + x;
        if (x + 1 < w_) {
          cap_[4 * n + 0] = right[n];
          cap_[4 * (n + 1) + 1] = right[n];
        }
        if (y + 1 < h_) {
          cap_[4 * n + 2] = down[n];
          cap_[4 * (n + w_) + 3] = down[n];
        }
        // Flow through source -> n -> sink directly (the tr_cap trick of the reference code).
        const Cap s = src[n], t = snk[n];
        flow += std::min(s, t);
        tr_cap_[n] = s - t;
        if (tr_cap_[n] > 0) {
          is_sink_[n] = 0;
          parent_[n] = kTerminal;
          SetActive(static_cast<std::int32_t>(n));
          ts_[n] = 0;
          dist_[n] = 1;
        } else if (tr_cap_[n] < 0) {
          is_sink_[n] = 1;
          parent_[n] = kTerminal;
          SetActive(static_cast<std::int32_t>(n));
          ts_[n] = 0;
          dist_[n] = 1;
        }
      }
    }
    flow += MainLoop();
    for (std::int64_t n = 0; n < n_; ++n) {
      sink_side[n] = (parent_[n] != kFree && is_sink_[n]) ? 1 : 0;
    }
    return flow;
  }

 private:
  std::int32_t Nb(std::int32_t n, int d) const { return n + off_[d]; }

  void SetActive(std::int32_t n) {
    if (next_[n] == kNotActive) {
      if (queue_last_[1] != kNotActive) {
        next_[queue_last_[1]] = n;
      } else {
        queue_first_[1] = n;
      }
      queue_last_[1] = n;
      next_[n] = n;
    }
  }

  std::int32_t NextActive() {
    for (;;) {
      std::int32_t i = queue_first_[0];
      if (i == kNotActive) {
        queue_first_[0] = i = queue_first_[1];
        queue_last_[0] = queue_last_[1];
        queue_first_[1] = queue_last_[1] = kNotActive;
        if (i == kNotActive) return kNotActive;
      }
      if (next_[i] == i) {
        queue_first_[0] = queue_last_[0] = kNotActive;
      } else {
        queue_first_[0] = next_[i];
      }
      next_[i] = kNotActive;
      if (parent_[i] != kFree) return i;
    }
  }

  void SetOrphanFront(std::int32_t n) {
    parent_[n] = kOrphan;
    orphans_.push_back(n);  // a stack: the last pushed is processed first ("front")
  }
  void SetOrphanRear(std::int32_t n) {
    parent_[n] = kOrphan;
    orphans_rear_.push_back(n);
  }

  Cap MainLoop() {
    Cap flow = 0;
    std::int32_t current = kNotActive;
    for (;;) {
      std::int32_t i = current;
      if (i != kNotActive) {
        next_[i] = kNotActive;
        if (parent_[i] == kFree) i = kNotActive;
      }
      if (i == kNotActive) {
        i = NextActive();
        if (i == kNotActive) break;
      }
      // Growth: look for an arc from the source tree to the sink tree.
      std::int32_t from = -1;  // middle arc from (source-tree node) in direction mid_dir
      int mid_dir = -1;
      const std::uint8_t ex = exists_[i];
      if (!is_sink_[i]) {
        for (int d = 0; d < 4; ++d) {
          if (!(ex >> d & 1) || cap_[4 * std::int64_t(i) + d] == 0) continue;
          const std::int32_t j = Nb(i, d);
          if (parent_[j] == kFree) {
            is_sink_[j] = 0;
            parent_[j] = static_cast<std::uint8_t>(d ^ 1);
            ts_[j] = ts_[i];
            dist_[j] = dist_[i] + 1;
            SetActive(j);
          } else if (is_sink_[j]) {
            from = i;
            mid_dir = d;
            break;
          } else if (ts_[j] <= ts_[i] && dist_[j] > dist_[i]) {
            parent_[j] = static_cast<std::uint8_t>(d ^ 1);
            ts_[j] = ts_[i];
            dist_[j] = dist_[i] + 1;
          }
        }
      } else {
        for (int d = 0; d < 4; ++d) {
          if (!(ex >> d & 1)) continue;
          const std::int32_t j = Nb(i, d);
          if (cap_[4 * std::int64_t(j) + (d ^ 1)] == 0) continue;  // arc j -> i
          if (parent_[j] == kFree) {
            is_sink_[j] = 1;
            parent_[j] = static_cast<std::uint8_t>(d ^ 1);
            ts_[j] = ts_[i];
            dist_[j] = dist_[i] + 1;
            SetActive(j);
          } else if (!is_sink_[j]) {
            from = j;
            mid_dir = d ^ 1;
            break;
          } else if (ts_[j] <= ts_[i] && dist_[j] > dist_[i]) {
            parent_[j] = static_cast<std::uint8_t>(d ^ 1);
            ts_[j] = ts_[i];
            dist_[j] = dist_[i] + 1;
          }
        }
      }
      ++time_;
      if (from >= 0) {
        next_[i] = i;  // keep i out of the active queue while it is the current node
        current = i;
        flow += Augment(from, mid_dir);
        // Adoption.
        for (;;) {
          std::int32_t o;
          if (!orphans_.empty()) {
            o = orphans_.back();
            orphans_.pop_back();
          } else if (rear_pos_ < orphans_rear_.size()) {
            o = orphans_rear_[rear_pos_++];
          } else {
            break;
          }
          if (is_sink_[o]) {
            ProcessOrphan<true>(o);
          } else {
            ProcessOrphan<false>(o);
          }
        }
        orphans_rear_.clear();
        rear_pos_ = 0;
      } else {
        current = kNotActive;
      }
    }
    return flow;
  }

  // Middle arc: from node a (source tree) in direction d to node b (sink tree).
  Cap Augment(std::int32_t a, int d) {
    const std::int32_t b = Nb(a, d);
    Cap bottleneck = cap_[4 * std::int64_t(a) + d];
    std::int32_t i = a;
    for (;;) {  // source tree: flow goes parent -> i, i.e. along the sister of i's parent arc
      const std::uint8_t p = parent_[i];
      if (p == kTerminal) break;
      const std::int32_t j = Nb(i, p);
      bottleneck = std::min(bottleneck, cap_[4 * std::int64_t(j) + (p ^ 1)]);
      i = j;
    }
    bottleneck = std::min(bottleneck, tr_cap_[i]);
    i = b;
    for (;;) {  // sink tree: flow goes i -> parent
      const std::uint8_t p = parent_[i];
      if (p == kTerminal) break;
      bottleneck = std::min(bottleneck, cap_[4 * std::int64_t(i) + p]);
      i = Nb(i, p);
    }
    bottleneck = std::min(bottleneck, -tr_cap_[i]);

    cap_[4 * std::int64_t(b) + (d ^ 1)] += bottleneck;
    cap_[4 * std::int64_t(a) + d] -= bottleneck;
    i = a;
    for (;;) {
      const std::uint8_t p = parent_[i];
      if (p == kTerminal) break;
      const std::int32_t j = Nb(i, p);
      cap_[4 * std::int64_t(i) + p] += bottleneck;
      Cap& rc = cap_[4 * std::int64_t(j) + (p ^ 1)];
      rc -= bottleneck;
      if (rc == 0) SetOrphanFront(i);
      i = j;
    }
    tr_cap_[i] -= bottleneck;
    if (tr_cap_[i] == 0) SetOrphanFront(i);
    i = b;
    for (;;) {
      const std::uint8_t p = parent_[i];
      if (p == kTerminal) break;
      const std::int32_t j = Nb(i, p);
      cap_[4 * std::int64_t(j) + (p ^ 1)] += bottleneck;
      Cap& rc = cap_[4 * std::int64_t(i) + p];
      rc -= bottleneck;
      if (rc == 0) SetOrphanFront(i);
      i = j;
    }
    tr_cap_[i] += bottleneck;
    if (tr_cap_[i] == 0) SetOrphanFront(i);
    return bottleneck;
  }

  // Residual capacity of the arc that would connect orphan i to candidate parent j = Nb(i, d)
  // inside the tree: source tree j -> i, sink tree i -> j.
  template <bool kSink>
  Cap TreeArcCap(std::int32_t i, int d) const {
    if (kSink) return cap_[4 * std::int64_t(i) + d];
    return cap_[4 * std::int64_t(Nb(i, d)) + (d ^ 1)];
  }

  template <bool kSink>
  void ProcessOrphan(std::int32_t i) {
    int best_dir = -1;
    int d_min = kInfiniteDist;
    const std::uint8_t ex = exists_[i];
    for (int d0 = 0; d0 < 4; ++d0) {
      if (!(ex >> d0 & 1) || TreeArcCap<kSink>(i, d0) == 0) continue;
      std::int32_t j = Nb(i, d0);
      if (static_cast<bool>(is_sink_[j]) != kSink || parent_[j] == kFree) continue;
      // Origin of j: walk to the terminal, stopping at a node checked at this time stamp.
      int dd = 0;
      for (;;) {
        if (ts_[j] == time_) {
          dd += dist_[j];
          break;
        }
        const std::uint8_t p = parent_[j];
        ++dd;
        if (p == kTerminal) {
          ts_[j] = time_;
          dist_[j] = 1;
          break;
        }
        if (p == kOrphan) {
          dd = kInfiniteDist;
          break;
        }
        j = Nb(j, p);
      }
      if (dd < kInfiniteDist) {
        if (dd < d_min) {
          best_dir = d0;
          d_min = dd;
        }
        for (j = Nb(i, d0); ts_[j] != time_; j = Nb(j, parent_[j])) {
          ts_[j] = time_;
          dist_[j] = dd--;
        }
      }
    }
    if (best_dir >= 0) {
      parent_[i] = static_cast<std::uint8_t>(best_dir);
      ts_[i] = time_;
      dist_[i] = d_min + 1;
      return;
    }
    parent_[i] = kFree;
    for (int d0 = 0; d0 < 4; ++d0) {
      if (!(ex >> d0 & 1)) continue;
      const std::int32_t j = Nb(i, d0);
      const std::uint8_t p = parent_[j];
      if (static_cast<bool>(is_sink_[j]) != kSink || p == kFree) continue;
      if (TreeArcCap<kSink>(i, d0) != 0) SetActive(j);
      if (p != kTerminal && p != kOrphan && Nb(j, p) == i) SetOrphanRear(j);
    }
  }

  int h_, w_;
  std::int64_t n_;
  std::int32_t off_[4];
  std::vector<Cap> cap_;
  std::vector<Cap> tr_cap_;
  std::vector<std::uint8_t> parent_, is_sink_, exists_;
  std::vector<std::int32_t> next_;
  std::vector<std::int32_t> ts_, dist_;
  std::vector<std::int32_t> orphans_, orphans_rear_;
  std::size_t rear_pos_ = 0;
  std::int32_t queue_first_[2] = {kNotActive, kNotActive};
  std::int32_t queue_last_[2] = {kNotActive, kNotActive};
  std::int32_t time_ = 0;
};

}  // namespace

template <typename Cap>
Cap GridMaxflowKernel(int height, int width, const Cap* source_cap, const Cap* sink_cap, const Cap* right,
                      const Cap* down, std::uint8_t* sink_side) {
  if (height <= 0 || width <= 0) return Cap(0);
  GridBK<Cap> bk(height, width);
  return bk.Run(source_cap, sink_cap, right, down, sink_side);
}

template std::int64_t GridMaxflowKernel<std::int64_t>(int, int, const std::int64_t*, const std::int64_t*,
                                                      const std::int64_t*, const std::int64_t*, std::uint8_t*);
template double GridMaxflowKernel<double>(int, int, const double*, const double*, const double*, const double*,
                                          std::uint8_t*);

}  // namespace ibr
