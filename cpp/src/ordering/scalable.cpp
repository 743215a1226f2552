// Region ordering for large instances (n >= kScalableMinRegions, docs/architecture.md §6): the
// neighbour-list local search and the scalable path of method best.
//
// Neighbour lists hold the kNeighbours nearest endpoints of every endpoint (other regions only).
// 2-opt and or-opt try only the moves that create a link to a listed neighbour (as in LKH), driven
// by a queue of the regions whose links changed (don't-look bits), so a converged path costs
// O(n k) to re-check instead of O(n^2) per pass. The iterated local search kicks with a local
// double bridge (two adjacent blocks of up to kKickBlock regions swap places), repairs by the
// queue, and keeps the kicked path only when it is shorter.
#include <algorithm>
#include <deque>
#include <numeric>
#include <utility>

#include "instance.hpp"

namespace shotcrete::ordering_internal {

namespace {

constexpr int kNeighbours = 10;
constexpr int kKickBlock = 30;
constexpr int kMaxBlock = 3;  // or-opt block length

// The k nearest endpoints of every endpoint (own region excluded), nearest first: a sweep along
// the axis of the largest extent, stopped on each side once the gap along it exceeds the k-th.
std::vector<int> neighbour_lists(const Instance& inst, int k) {
  const int E = inst.E;
  std::vector<int> out(static_cast<size_t>(E) * static_cast<size_t>(k), -1);
  Eigen::Vector3d lo = inst.pts[0], hi = inst.pts[0];
  for (int e = 0; e < E; ++e) {
    lo = lo.cwiseMin(inst.pts[static_cast<size_t>(e)]);
    hi = hi.cwiseMax(inst.pts[static_cast<size_t>(e)]);
  }
  int axis = 0;
  (hi - lo).maxCoeff(&axis);
  auto key = [&](int e) { return inst.pts[static_cast<size_t>(e)][axis]; };
  std::vector<int> order(static_cast<size_t>(E)), rank(static_cast<size_t>(E));
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return key(a) < key(b) || (key(a) == key(b) && a < b); });
  for (int r = 0; r < E; ++r) rank[static_cast<size_t>(order[static_cast<size_t>(r)])] = r;
  std::vector<std::pair<double, int>> heap;  // max-heap of (distance, endpoint)
  for (int e = 0; e < E; ++e) {
    heap.clear();
    const auto scan = [&](int r) {  // false once nothing farther along the axis can enter
      const int f = order[static_cast<size_t>(r)];
      if (static_cast<int>(heap.size()) == k && std::abs(key(f) - key(e)) > heap.front().first) return false;
      if ((f >> 1) == (e >> 1)) return true;
      const std::pair<double, int> c{inst.d(e, f), f};
      if (static_cast<int>(heap.size()) < k) {
        heap.push_back(c);
        std::push_heap(heap.begin(), heap.end());
      } else if (c < heap.front()) {
        std::pop_heap(heap.begin(), heap.end());
        heap.back() = c;
        std::push_heap(heap.begin(), heap.end());
      }
      return true;
    };
    for (int r = rank[static_cast<size_t>(e)] + 1; r < E && scan(r); ++r) {
    }
    for (int r = rank[static_cast<size_t>(e)] - 1; r >= 0 && scan(r); --r) {
    }
    std::sort_heap(heap.begin(), heap.end());
    for (size_t j = 0; j < heap.size(); ++j) out[static_cast<size_t>(e) * k + j] = heap[j].second;
  }
  return out;
}

struct Move {
  double delta = -kImprove;  // only moves that gain more than kImprove are taken
  bool two_opt = false;      // reverse s[i..j]; else move the block s[i..i+len-1] to gap g
  int i = 0, j = 0, len = 0, g = 0;
  bool rev = false;
};

// A path with the position of every region, the neighbour lists and the work queue.
class NeighbourSearch {
 public:
  NeighbourSearch(const Instance& inst, Path s) : inst_(inst), n_(inst.n), s_(std::move(s)) {
    k_ = std::min(kNeighbours, std::max(0, inst.E - 2));
    nb_ = neighbour_lists(inst, k_);
    pos_.assign(static_cast<size_t>(n_), 0);
    queued_.assign(static_cast<size_t>(n_), 0);
    reindex(0, n_);
  }
  const Path& path() const { return s_; }
  Path& path() { return s_; }
  std::vector<int>& positions() { return pos_; }

  // Queue every region (in path order) and improve until the queue is empty; returns the gain (< 0).
  double run_all() {
    for (int p = 0; p < n_; ++p) push_at(p);
    return run();
  }
  void push_at(int p) {
    if (p < 0 || p >= n_) return;
    const int r = s_[static_cast<size_t>(p)] >> 1;
    if (queued_[static_cast<size_t>(r)]) return;
    queued_[static_cast<size_t>(r)] = 1;
    queue_.push_back(r);
  }
  double run() {
    double gain = 0.0;
    while (!queue_.empty()) {
      const int r = queue_.front();
      queue_.pop_front();
      queued_[static_cast<size_t>(r)] = 0;
      const Move m = best_move(pos_[static_cast<size_t>(r)]);
      if (m.delta >= -kImprove) continue;
      apply(m);
      gain += m.delta;
      push_at(pos_[static_cast<size_t>(r)]);
    }
    return gain;
  }
  void reindex(int a, int b) {
    for (int p = std::max(a, 0); p < std::min(b, n_); ++p) pos_[static_cast<size_t>(s_[static_cast<size_t>(p)] >> 1)] = p;
  }
  int row_before(int p) const { return p == 0 ? inst_.E : (s_[static_cast<size_t>(p - 1)] ^ 1); }
  double link_in(int p) const { return p < n_ ? inst_.d(row_before(p), s_[static_cast<size_t>(p)]) : 0.0; }

 private:
  int at(int p) const { return s_[static_cast<size_t>(p)]; }
  const int* neighbours(int e) const { return nb_.data() + static_cast<size_t>(e) * k_; }

  double reverse_delta(int i, int j) const {
    const int P = row_before(i);
    const bool has_next = j + 1 < n_;
    const double before = inst_.d(P, at(i)) + (has_next ? inst_.d(at(j) ^ 1, at(j + 1)) : 0.0);
    const double after = inst_.d(P, at(j) ^ 1) + (has_next ? inst_.d(at(i), at(j + 1)) : 0.0);
    return after - before;
  }
  double move_delta(int i, int len, int g, bool rev) const {
    const int first = at(i), last_exit = at(i + len - 1) ^ 1, P = row_before(i);
    const bool has_next = i + len < n_;
    const double removal = inst_.d(P, first) + (has_next ? inst_.d(last_exit, at(i + len)) - inst_.d(P, at(i + len)) : 0.0);
    const int x = g == 0 ? inst_.E : (at(g - 1) ^ 1);
    const bool has_y = g < n_;
    const double base = has_y ? -inst_.d(x, at(g)) : 0.0;
    const double ins = rev ? inst_.d(x, last_exit) + (has_y ? inst_.d(first, at(g)) : 0.0)
                           : inst_.d(x, first) + (has_y ? inst_.d(last_exit, at(g)) : 0.0);
    return ins + base - removal;
  }
  void consider_reverse(Move& best, int i, int j) const {
    if (i < 0 || j >= n_ || i > j) return;
    const double d = reverse_delta(i, j);
    if (d < best.delta) best = Move{d, true, i, j, 0, 0, false};
  }
  void consider_gap(Move& best, int i, int len, int g) const {
    if (g >= i && g <= i + len) return;
    for (bool rev : {false, true}) {
      const double d = move_delta(i, len, g, rev);
      if (d < best.delta) best = Move{d, false, i, 0, len, g, rev};
    }
  }
  // The block s[i..i+len-1] next to a neighbour of one of its ends, or at either end of the path.
  void consider_block(Move& best, int i, int len) const {
    if (i < 0 || i + len > n_) return;
    consider_gap(best, i, len, 0);
    consider_gap(best, i, len, n_);
    for (int end : {at(i), at(i + len - 1) ^ 1}) {
      const int* c = neighbours(end);
      for (int t = 0; t < k_; ++t) {
        if (c[t] < 0) break;
        const int q = pos_[static_cast<size_t>(c[t] >> 1)];
        consider_gap(best, i, len, c[t] == at(q) ? q : q + 1);  // before an entry, after an exit
      }
    }
  }
  // The best move that links an endpoint of the region at position p to one of its neighbours, or
  // to an end of the open path (reversing the prefix before p or the suffix after it).
  Move best_move(int p) const {
    Move best;
    consider_reverse(best, 0, p - 1);
    consider_reverse(best, p + 1, n_ - 1);
    const int entry = at(p), exit = entry ^ 1;
    for (int t = 0; t < k_; ++t) {
      const int c = neighbours(exit)[t];
      if (c >= 0) {
        const int q = pos_[static_cast<size_t>(c >> 1)];
        if (c == (at(q) ^ 1)) q > p ? consider_reverse(best, p + 1, q) : consider_reverse(best, q + 1, p);
      }
      const int c2 = neighbours(entry)[t];
      if (c2 >= 0) {
        const int q = pos_[static_cast<size_t>(c2 >> 1)];
        if (c2 == at(q)) q < p ? consider_reverse(best, q, p - 1) : consider_reverse(best, p, q - 1);
      }
    }
    for (int len = 1; len <= kMaxBlock; ++len) {
      consider_block(best, p, len);
      if (len > 1) consider_block(best, p - len + 1, len);
    }
    return best;
  }
  void apply(const Move& m) {
    if (m.two_opt) {
      std::reverse(s_.begin() + m.i, s_.begin() + m.j + 1);
      for (int p = m.i; p <= m.j; ++p) s_[static_cast<size_t>(p)] ^= 1;
      reindex(m.i, m.j + 1);
      for (int p : {m.i - 1, m.i, m.j, m.j + 1}) push_at(p);
      return;
    }
    int start = 0, lo = 0, hi = 0;
    if (m.g < m.i) {
      std::rotate(s_.begin() + m.g, s_.begin() + m.i, s_.begin() + m.i + m.len);
      start = m.g, lo = m.g, hi = m.i + m.len;
    } else {
      std::rotate(s_.begin() + m.i, s_.begin() + m.i + m.len, s_.begin() + m.g);
      start = m.g - m.len, lo = m.i, hi = m.g;
    }
    if (m.rev) {
      std::reverse(s_.begin() + start, s_.begin() + start + m.len);
      for (int p = start; p < start + m.len; ++p) s_[static_cast<size_t>(p)] ^= 1;
    }
    reindex(lo, hi);
    for (int p : {lo - 1, lo, start - 1, start, start + m.len - 1, start + m.len, hi - 1, hi}) push_at(p);
  }

  const Instance& inst_;
  int n_ = 0, k_ = 0;
  Path s_;
  std::vector<int> pos_, nb_;
  std::vector<char> queued_;
  std::deque<int> queue_;
};

// Swap the adjacent blocks s[i..i+a-1] and s[i+a..i+a+b-1]; returns the change of length.
double local_double_bridge(NeighbourSearch& ns, int i, int a, int b) {
  double before = 0.0, after = 0.0;
  for (int p : {i, i + a, i + a + b}) before += ns.link_in(p);
  Path& s = ns.path();
  std::rotate(s.begin() + i, s.begin() + i + a, s.begin() + i + a + b);
  ns.reindex(i, i + a + b);
  for (int p : {i, i + b, i + a + b}) after += ns.link_in(p);
  for (int p : {i - 1, i, i + b - 1, i + b, i + a + b - 1, i + a + b}) ns.push_at(p);
  return after - before;
}

}  // namespace

void local_search_neighbours(const Instance& inst, Path& s) {
  NeighbourSearch ns(inst, std::move(s));
  ns.run_all();
  s = ns.path();
}

Path scalable_path(const Instance& inst, const OrderingProblem& p, const OrderingConfig& cfg, const RunControl& ctl) {
  if (inst.n == 0) return {};
  ctl.report("nearest neighbour", 0.0);
  NeighbourSearch ns(inst, nearest_neighbour_path(inst, p));
  ctl.report("nearest neighbour", 1.0);
  ctl.report("local search", 0.0);
  ns.run_all();
  ctl.report("local search", 1.0);
  const int n = inst.n;
  const long kicks = static_cast<long>(cfg.ils_kicks_per_region) * n;
  std::mt19937_64 rng(cfg.seed ^ 0x9E3779B97F4A7C15ULL);
  double cost = inst.cost(ns.path());
  Path saved_s;
  std::vector<int> saved_pos;
  for (long k = 0; k < kicks && n >= 3; ++k) {
    ctl.report("iterated local search", static_cast<double>(k) / static_cast<double>(kicks));
    if (ctl.spent()) break;  // time_budget_s: the best so far
    const int i = uniform_int(rng, n - 1);
    const int a = 1 + uniform_int(rng, std::min(kKickBlock, n - i - 1));
    const int b = 1 + uniform_int(rng, std::min(kKickBlock, n - i - a));
    if (i + a + b > n) continue;
    saved_s = ns.path();
    saved_pos = ns.positions();
    const double kicked = cost + local_double_bridge(ns, i, a, b);
    const double repaired = kicked + ns.run();
    if (repaired < cost - kImprove) {
      cost = repaired;
    } else {
      ns.path().swap(saved_s);
      ns.positions().swap(saved_pos);
    }
  }
  ctl.report("iterated local search", 1.0);
  return ns.path();
}

}  // namespace shotcrete::ordering_internal
