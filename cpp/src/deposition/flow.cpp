// The pump's flow schedule from spraying flags: minimum on / off spells, centred linear ramps,
// and the flow-weighted dwell of every sample (see flow.hpp).
#include "shotcrete/deposition/flow.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
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

// Merges spells separated by less than min_off; returns whether any were merged.
bool bridge_gaps(FlowSchedule& s, double min_off) {
  std::vector<double> on, off;
  bool merged = false;
  for (std::size_t k = 0; k < s.on_s.size(); ++k) {
    if (!on.empty() && s.on_s[k] - off.back() < min_off) {
      s.bridged_s += std::max(0.0, s.on_s[k] - off.back());
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

// Extends spells shorter than min_on about their middle, within [t0, t1]; returns whether any grew.
bool extend_spells(FlowSchedule& s, double min_on, double t0, double t1) {
  bool grown = false;
  const double target = std::min(min_on, t1 - t0);
  for (std::size_t k = 0; k < s.on_s.size(); ++k) {
    double& a = s.on_s[k];
    double& b = s.off_s[k];
    const double need = target - (b - a);
    if (!(need > 1e-12)) continue;
    a -= 0.5 * need;
    b += 0.5 * need;
    if (a < t0) b += t0 - a, a = t0;
    if (b > t1) a = std::max(t0, a - (b - t1)), b = t1;
    grown = true;
  }
  return grown;
}

void check_times(const std::vector<double>& t_s) {
  for (std::size_t i = 0; i < t_s.size(); ++i) {
    if (!std::isfinite(t_s[i])) throw std::invalid_argument("flow_schedule: t_s[" + std::to_string(i) + "] is not finite");
    if (i > 0 && !(t_s[i] > t_s[i - 1]))
      throw std::invalid_argument("flow_schedule: t_s must increase strictly (t_s[" + std::to_string(i) +
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

FlowSchedule flow_schedule(const std::vector<double>& t_s, const std::vector<char>& spraying, const FlowConfig& flow) {
  Config c;
  c.flow = flow;
  validate(c);
  if (t_s.size() != spraying.size())
    throw std::invalid_argument("flow_schedule: " + std::to_string(t_s.size()) + " times but " +
                                std::to_string(spraying.size()) + " spraying flags");
  check_times(t_s);
  FlowSchedule s;
  s.ramp_s = flow.ramp_s;
  if (t_s.empty()) return s;
  commanded_spells(t_s, spraying, s);
  s.commanded_on_s = s.on_time_s();
  s.commanded_switches = s.switches();
  // Bridging only merges and extending only lengthens, so this settles; the cap is a safeguard.
  for (int pass = 0; pass < 1000; ++pass) {
    const bool merged = bridge_gaps(s, flow.min_off_s);
    const bool grown = extend_spells(s, flow.min_on_s, t_s.front(), t_s.back());
    if (!merged && !grown) break;
  }
  s.extended_s = s.on_time_s() - s.commanded_on_s - s.bridged_s;
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
  double prev = 0.0;  // integral to the lower edge of sample i's share (-infinity for the first)
  for (std::size_t i = 0; i + 1 < n; ++i) {
    const double cur = cumulative(0.5 * (t_s[i] + t_s[i + 1]));
    dwell[i] = cur - prev;
    prev = cur;
  }
  dwell[n - 1] = s.on_time_s() - prev;
  return dwell;
}

}  // namespace shotcrete
