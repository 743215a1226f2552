// The pump's flow schedule from spraying flags: minimum on / off spells, centred linear ramps,
// and the flow-weighted dwell of every sample (see flow.hpp).
#include "shotcrete/deposition/flow.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>

namespace shotcrete {

namespace {

// Integral from -infinity to t of a unit step at c smoothed into a linear ramp of width r centred
// on c: 0 before the ramp, (t - c + r/2)^2 / (2 r) on it, t - c after it.
double ramp_integral(double t, double c, double r) {
  if (!(r > 0.0)) return std::max(0.0, t - c);
  if (t <= c - 0.5 * r) return 0.0;
  if (t >= c + 0.5 * r) return t - c;
  const double u = t - c + 0.5 * r;
  return u * u / (2.0 * r);
}

double ramp_value(double t, double c, double r) {
  if (!(r > 0.0)) return t >= c ? 1.0 : 0.0;
  return std::clamp((t - c + 0.5 * r) / r, 0.0, 1.0);
}

// Spells [on, off] the flags ask for: a flagged sample stands for the time between the midpoints
// with its neighbours (the first and last samples reach the trajectory's ends).
void commanded_spells(const std::vector<double>& t, const std::vector<char>& spraying, FlowSchedule& s) {
  const std::size_t n = t.size();
  for (std::size_t i = 0; i < n; ++i) {
    if (!spraying[i] || (i > 0 && spraying[i - 1])) continue;
    std::size_t j = i;
    while (j + 1 < n && spraying[j + 1]) ++j;
    s.on_s.push_back(i == 0 ? t[0] : 0.5 * (t[i - 1] + t[i]));
    s.off_s.push_back(j + 1 == n ? t[n - 1] : 0.5 * (t[j] + t[j + 1]));
  }
}

// Free stretches of time between blocked samples (joint moves), each shrunk by half a ramp at a
// blocked end so that no ramp reaches into a joint move; the samples' own ends stay unless
// ends_blocked (a region of a trajectory between two joint moves).
struct Windows {
  std::vector<double> lo, hi;
  // Index of the window holding time t (-1: none).
  int at(double t) const {
    for (std::size_t w = 0; w < lo.size(); ++w)
      if (t >= lo[w] - 1e-9 && t <= hi[w] + 1e-9) return static_cast<int>(w);
    return -1;
  }
};

Windows free_windows(const std::vector<double>& t, const std::vector<char>& blocked, double ramp_s, bool ends_blocked) {
  const std::size_t n = t.size();
  Windows w;
  const double half = 0.5 * std::max(0.0, ramp_s);
  // ends_blocked: the first sample is the joint move's last (time_plan joins them at the lead's
  // start), and the next joint move starts one sample interval after the last sample.
  const double dt_end = n > 1 ? t[n - 1] - t[n - 2] : 0.0;
  double start = ends_blocked && n > 1 ? 0.5 * (t[0] + t[1]) : t.front();
  bool start_blocked = ends_blocked;
  for (std::size_t i = 0; i < n;) {
    if (blocked.empty() || !blocked[i]) {
      ++i;
      continue;
    }
    std::size_t j = i;
    while (j + 1 < n && blocked[j + 1]) ++j;
    const double b_lo = i == 0 ? t.front() : 0.5 * (t[i - 1] + t[i]);
    const double b_hi = j + 1 == n ? t.back() : 0.5 * (t[j] + t[j + 1]);
    const double lo = start + (start_blocked ? half : 0.0), hi = b_lo - half;
    if (hi > lo) w.lo.push_back(lo), w.hi.push_back(hi);
    start = b_hi, start_blocked = true;
    i = j + 1;
  }
  const double lo = start + (start_blocked ? half : 0.0), hi = ends_blocked ? t.back() + 0.5 * dt_end - half : t.back();
  if (hi > lo) w.lo.push_back(lo), w.hi.push_back(hi);
  return w;
}

// Spells clipped into the free window they overlap most (the flags' spells never hold a blocked
// sample, but their ramps may reach one); spells left empty are dropped. Afterwards every spell
// lies inside one window, so the later steps find it by its middle (Windows::at).
void clip_to_windows(FlowSchedule& s, const Windows& w) {
  std::vector<double> on, off;
  for (std::size_t k = 0; k < s.on_s.size(); ++k) {
    const double length = s.off_s[k] - s.on_s[k];
    // The window the spell overlaps most.
    int best = -1;
    double most = 0.0;
    for (std::size_t v = 0; v < w.lo.size(); ++v) {
      const double overlap = std::min(s.off_s[k], w.hi[v]) - std::max(s.on_s[k], w.lo[v]);
      if (overlap > most) most = overlap, best = static_cast<int>(v);
    }
    if (best < 0) {
      s.dropped_s += length;
      continue;
    }
    s.dropped_s += length - most;
    on.push_back(std::max(s.on_s[k], w.lo[static_cast<std::size_t>(best)]));
    off.push_back(std::min(s.off_s[k], w.hi[static_cast<std::size_t>(best)]));
  }
  s.on_s = std::move(on);
  s.off_s = std::move(off);
}

// The part of `need` taken on the side before when both sides can give (before + after >= need):
// half, or more where the side after has less than half (std::clamp's bounds may cross by
// rounding there).
double share_before(double need, double before, double after) {
  return std::min(before, std::max(need - after, 0.5 * need));
}

// A gap shorter than min_off within one free window (across a joint move the flow is never kept
// on) is widened to min_off by switching off earlier and on later, when that cuts less commanded
// flow than bridging would add (min_off - gap < gap) and both spells keep min_on; otherwise the
// spells are merged (the pump runs through the gap). A bridged turn-around lays its whole duration
// where the nozzle turns, a pile the planner cannot take back (40 mm on the default bay with fast
// turns); the ends cut off two passes are spread along them. Returns whether anything changed.
bool bridge_gaps(FlowSchedule& s, double min_off, double min_on, const Windows* w) {
  std::vector<double> on, off;
  bool merged = false;
  for (std::size_t k = 0; k < s.on_s.size(); ++k) {
    const double gap = on.empty() ? 0.0 : s.on_s[k] - off.back();
    if (!on.empty() && gap < min_off - 1e-12 && (w == nullptr || w->at(off.back()) == w->at(s.on_s[k]))) {
      const double need = min_off - gap;
      const double spare_before = off.back() - on.back() - min_on, spare_after = s.off_s[k] - s.on_s[k] - min_on;
      if (gap > 0.0 && need < gap && spare_before >= 0.0 && spare_after >= 0.0 && spare_before + spare_after >= need) {
        const double cut_before = share_before(need, spare_before, spare_after);
        off.back() -= cut_before;
        on.push_back(s.on_s[k] + (need - cut_before));
        off.push_back(s.off_s[k]);
        s.trimmed_s += need;
        merged = true;
        continue;
      }
      s.bridged_s += std::max(0.0, gap);
      off.back() = std::max(off.back(), s.off_s[k]);
      merged = true;
      continue;
    }
    on.push_back(s.on_s[k]);
    off.push_back(s.off_s[k]);
  }
  s.on_s = std::move(on);
  s.off_s = std::move(off);
  return merged;
}

// Extends spells shorter than min_on about their middle, within [t0, t1] and within their free
// window; a spell whose window is shorter than min_on cannot be served by the pump and is dropped
// (switched off). Returns whether any spell grew or was dropped.
bool extend_spells(FlowSchedule& s, double min_on, double t0, double t1, const Windows* w) {
  bool changed = false;
  std::vector<double> on, off;
  for (std::size_t k = 0; k < s.on_s.size(); ++k) {
    double a = s.on_s[k], b = s.off_s[k];
    double lo = t0, hi = t1;
    if (w != nullptr) {
      const int v = w->at(0.5 * (a + b));
      if (v >= 0) lo = std::max(lo, w->lo[static_cast<std::size_t>(v)]), hi = std::min(hi, w->hi[static_cast<std::size_t>(v)]);
    }
    const double target = w == nullptr ? std::min(min_on, t1 - t0) : min_on;
    const double need = target - (b - a);
    if (need > 1e-12) {
      if (hi - lo < target - 1e-12) {  // the pump cannot run this short a spell here
        s.dropped_s += b - a;
        changed = true;
        continue;
      }
      a -= 0.5 * need;
      b += 0.5 * need;
      if (a < lo) b += lo - a, a = lo;
      if (b > hi) a = std::max(lo, a - (b - hi)), b = hi;
      changed = true;
    }
    on.push_back(a);
    off.push_back(b);
  }
  s.on_s = std::move(on);
  s.off_s = std::move(off);
  return changed;
}

// Across a joint move the flow is off for the move and its ramps; if that gap is still shorter
// than min_off, the shorter of the two spells is switched off. Returns whether one was. A short
// gap inside one free window is bridge_gaps' (it was dropping a spell that an extension had
// brought within min_off of its neighbours, or bridging it, by the order the gaps came in: a
// region's schedule and the whole trajectory's disagreed, 39 mm on a cell).
bool drop_short_blocked_gaps(FlowSchedule& s, double min_off, const Windows& w) {
  for (std::size_t k = 1; k < s.on_s.size(); ++k) {
    if (s.on_s[k] - s.off_s[k - 1] >= min_off) continue;
    if (w.at(s.off_s[k - 1]) == w.at(s.on_s[k])) continue;
    const std::size_t drop = s.off_s[k - 1] - s.on_s[k - 1] <= s.off_s[k] - s.on_s[k] ? k - 1 : k;
    s.dropped_s += s.off_s[drop] - s.on_s[drop];
    s.on_s.erase(s.on_s.begin() + static_cast<std::ptrdiff_t>(drop));
    s.off_s.erase(s.off_s.begin() + static_cast<std::ptrdiff_t>(drop));
    return true;
  }
  return false;
}

void check_times(const char* who, const std::vector<double>& t_s) {
  for (std::size_t i = 0; i < t_s.size(); ++i) {
    if (!std::isfinite(t_s[i])) throw std::invalid_argument(std::string(who) + ": t_s[" + std::to_string(i) + "] is not finite");
    if (i > 0 && !(t_s[i] > t_s[i - 1]))
      throw std::invalid_argument(std::string(who) + ": t_s must increase strictly (t_s[" + std::to_string(i) +
                                  "] = " + std::to_string(t_s[i]) + ")");
  }
}

}  // namespace

double FlowSchedule::shortest_on_s() const {
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < on_s.size(); ++k) best = std::min(best, off_s[k] - on_s[k]);
  return on_s.empty() ? 0.0 : best;
}

double FlowSchedule::shortest_off_s() const {
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t k = 1; k < on_s.size(); ++k) best = std::min(best, on_s[k] - off_s[k - 1]);
  return on_s.size() < 2 ? 0.0 : best;
}

double FlowSchedule::on_time_s() const {
  double sum = 0.0;
  for (std::size_t k = 0; k < on_s.size(); ++k) sum += off_s[k] - on_s[k];
  return sum;
}

double FlowSchedule::flow_at(double t) const {
  double f = 0.0;
  for (std::size_t k = 0; k < on_s.size(); ++k) f += ramp_value(t, on_s[k], ramp_s) - ramp_value(t, off_s[k], ramp_s);
  return std::clamp(f, 0.0, 1.0);
}

double FlowSchedule::integral_to(double t) const {
  double sum = 0.0;
  for (std::size_t k = 0; k < on_s.size(); ++k) sum += ramp_integral(t, on_s[k], ramp_s) - ramp_integral(t, off_s[k], ramp_s);
  return sum;
}

namespace {

void check_inputs(const char* who, const std::vector<double>& t_s, const FlowConfig& flow, const std::vector<char>& blocked) {
  Config c;
  c.flow = flow;
  validate(c);
  if (!blocked.empty() && blocked.size() != t_s.size())
    throw std::invalid_argument(std::string(who) + ": " + std::to_string(t_s.size()) + " times but " +
                                std::to_string(blocked.size()) + " blocked flags");
  check_times(who, t_s);
}

// A program laid out on other durations (the planner's timing of a region) runs on the arm's: a
// spell or a gap that came out a little shorter than its minimum is stretched into the slack of
// its neighbours (gaps longer than min_off, spells longer than min_on, the free time to the ends
// of its window), as the program meant it, before the general rules (which bridge such a gap)
// see it. Spells lie in their windows (clip_to_windows) and stay there; a gap across a joint move
// is drop_short_blocked_gaps'.
void stretch_to_minimums(FlowSchedule& s, double min_on, double min_off, double t0, double t1, const Windows* w) {
  const std::size_t n = s.on_s.size();
  auto window_of = [&](std::size_t k) { return w == nullptr ? -1 : w->at(0.5 * (s.on_s[k] + s.off_s[k])); };
  auto lo_of = [&](std::size_t k) { const int v = window_of(k); return v < 0 ? t0 : w->lo[static_cast<std::size_t>(v)]; };
  auto hi_of = [&](std::size_t k) { const int v = window_of(k); return v < 0 ? t1 : w->hi[static_cast<std::size_t>(v)]; };
  auto same_window = [&](std::size_t a, std::size_t b) { return w == nullptr || window_of(a) == window_of(b); };
  for (std::size_t k = 0; k < n; ++k) {
    const double need = min_on - (s.off_s[k] - s.on_s[k]);
    if (need <= 1e-12) continue;
    const double before = std::max(0.0, k > 0 && same_window(k - 1, k) ? s.on_s[k] - s.off_s[k - 1] - min_off : s.on_s[k] - lo_of(k));
    const double after = std::max(0.0, k + 1 < n && same_window(k, k + 1) ? s.on_s[k + 1] - s.off_s[k] - min_off : hi_of(k) - s.off_s[k]);
    if (before + after < need) continue;
    const double grow_before = share_before(need, before, after);
    s.on_s[k] -= grow_before;
    s.off_s[k] += need - grow_before;
  }
  for (std::size_t k = 1; k < n; ++k) {
    const double need = min_off - (s.on_s[k] - s.off_s[k - 1]);
    if (need <= 1e-12 || !same_window(k - 1, k)) continue;
    // Each spell keeps min_on (and some length when that is 0).
    const double keep = std::max(min_on, 1e-6);
    const double before = std::max(0.0, s.off_s[k - 1] - s.on_s[k - 1] - keep);
    const double after = std::max(0.0, s.off_s[k] - s.on_s[k] - keep);
    if (before + after < need) continue;
    const double cut_before = share_before(need, before, after);
    s.off_s[k - 1] -= cut_before;
    s.on_s[k] += need - cut_before;
    s.trimmed_s += need;
  }
}

// The commanded spells of `s` (set) made into what the pump runs: flow_schedule's rules, after
// stretch_to_minimums for a program.
void settle(FlowSchedule& s, const std::vector<double>& t_s, const FlowConfig& flow, const std::vector<char>& blocked,
            bool ends_blocked, bool stretch) {
  std::optional<Windows> windows;
  if (ends_blocked || std::find(blocked.begin(), blocked.end(), 1) != blocked.end()) {
    windows = free_windows(t_s, blocked, flow.ramp_s, ends_blocked);
    clip_to_windows(s, *windows);
  }
  const Windows* w = windows ? &*windows : nullptr;
  if (stretch) stretch_to_minimums(s, flow.min_on_s, flow.min_off_s, t_s.front(), t_s.back(), w);
  // Bridging only merges, extending only lengthens and dropping only removes, so this settles;
  // the cap is a safeguard.
  for (int pass = 0; pass < 1000; ++pass) {
    const bool merged = bridge_gaps(s, flow.min_off_s, flow.min_on_s, w);
    const bool grown = extend_spells(s, flow.min_on_s, t_s.front(), t_s.back(), w);
    const bool dropped = w != nullptr && drop_short_blocked_gaps(s, flow.min_off_s, *w);
    if (!merged && !grown && !dropped) break;
  }
  s.extended_s = s.on_time_s() - s.commanded_on_s - s.bridged_s + s.dropped_s + s.trimmed_s;
}

}  // namespace

FlowSchedule flow_schedule(const std::vector<double>& t_s, const std::vector<char>& spraying, const FlowConfig& flow,
                           const std::vector<char>& blocked, bool ends_blocked) {
  check_inputs("flow_schedule", t_s, flow, blocked);
  if (t_s.size() != spraying.size())
    throw std::invalid_argument("flow_schedule: " + std::to_string(t_s.size()) + " times but " +
                                std::to_string(spraying.size()) + " spraying flags");
  FlowSchedule s;
  s.ramp_s = flow.ramp_s;
  if (t_s.empty()) return s;
  commanded_spells(t_s, spraying, s);
  s.commanded_on_s = s.on_time_s();
  s.commanded_switches = s.switches();
  settle(s, t_s, flow, blocked, ends_blocked, /*stretch=*/false);
  return s;
}

FlowSchedule program_schedule(const std::vector<double>& on_s, const std::vector<double>& off_s,
                              const std::vector<double>& t_s, const FlowConfig& flow, const std::vector<char>& blocked,
                              bool ends_blocked) {
  check_inputs("program_schedule", t_s, flow, blocked);
  if (on_s.size() != off_s.size())
    throw std::invalid_argument("program_schedule: " + std::to_string(on_s.size()) + " switches on but " +
                                std::to_string(off_s.size()) + " off");
  for (std::size_t k = 0; k < on_s.size(); ++k) {
    if (!std::isfinite(on_s[k]) || !std::isfinite(off_s[k]) || !(off_s[k] > on_s[k]) || (k > 0 && !(on_s[k] > off_s[k - 1])))
      throw std::invalid_argument("program_schedule: spell " + std::to_string(k) + " [" + std::to_string(on_s[k]) + ", " +
                                  std::to_string(off_s[k]) + "] s is empty, not finite or not after the one before");
    if (!t_s.empty() && (on_s[k] < t_s.front() - 1e-9 || off_s[k] > t_s.back() + 1e-9))
      throw std::invalid_argument("program_schedule: spell " + std::to_string(k) + " lies outside the samples' times");
  }
  FlowSchedule s;
  s.ramp_s = flow.ramp_s;
  if (t_s.empty()) return s;
  s.on_s = on_s;
  s.off_s = off_s;
  s.commanded_on_s = s.on_time_s();
  s.commanded_switches = s.switches();
  settle(s, t_s, flow, blocked, ends_blocked, /*stretch=*/true);
  return s;
}

std::vector<double> flow_dwells(const FlowSchedule& s, const std::vector<double>& t_s) {
  const std::size_t n = t_s.size();
  std::vector<double> dwell(n, 0.0);
  if (n == 0 || s.on_s.empty()) return dwell;
  const double half = 0.5 * s.ramp_s;
  std::size_t first = 0;  // first spell whose off-ramp has not ended by t
  double done = 0.0;      // flow-on time of the spells before `first`
  // Integral to t for increasing t: the ended spells summed once, the others (at most a few, the
  // spells being ramp_s or more apart) integrated.
  auto cumulative = [&](double t) {
    while (first < s.on_s.size() && s.off_s[first] + half <= t) done += s.off_s[first] - s.on_s[first], ++first;
    double sum = done;
    for (std::size_t k = first; k < s.on_s.size() && s.on_s[k] - half < t; ++k)
      sum += ramp_integral(t, s.on_s[k], s.ramp_s) - ramp_integral(t, s.off_s[k], s.ramp_s);
    return sum;
  };
  // A share's dwell is a difference of two running integrals, which cancels: just before an
  // off-ramp's end the integral still holds t - on minus the ramp's square, just after it off - on,
  // and a share 64 ns before a ramp's end at t = 26.7 s read -3.6e-15 s, which accumulate_dwells
  // refuses (bench_axis, seed 1 turned 135 deg). The flow is never negative, so neither is a
  // share: what goes below 0 is rounding, and is cut there.
  double prev = 0.0;  // integral to the lower edge of sample i's share (-infinity for the first)
  for (std::size_t i = 0; i + 1 < n; ++i) {
    const double cur = cumulative(0.5 * (t_s[i] + t_s[i + 1]));
    dwell[i] = std::max(0.0, cur - prev);
    prev = cur;
  }
  dwell[n - 1] = std::max(0.0, s.on_time_s() - prev);
  return dwell;
}

}  // namespace shotcrete
