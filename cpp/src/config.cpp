#include "shotcrete/config.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>
#include <type_traits>

#include "shotcrete/config_fields.hpp"
#include "shotcrete/io/text.hpp"

namespace shotcrete {
namespace {

template <class T> void read_value(const YAML::Node& node, const std::string& key, T& out) {
  try {
    if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
      if (!node.IsSequence() || node.size() != 3)
        throw std::invalid_argument("config key '" + key + "': expected a list of 3 numbers");
      for (int i = 0; i < 3; ++i) out[i] = node[i].as<double>();
    } else if constexpr (std::is_same_v<T, bool>) {
      // A quoted "yes" is text, not a boolean (the Python loader says the same).
      if (!node.IsScalar() || node.Tag() == "!")
        throw std::invalid_argument("config key '" + key + "' must be true or false (a YAML boolean), got " +
                                    (node.IsScalar() ? "the quoted text " : std::string()) + "'" + printable(YAML::Dump(node)) + "'");
      out = node.as<bool>();
    } else if constexpr (is_named_enum_v<T>) {
      if (!node.IsScalar()) throw std::invalid_argument("config key '" + key + "': expected one of " + enum_choices<T>());
      out = parse_enum<T>(node.as<std::string>(), "config key '" + key + "'");
    } else if constexpr (std::is_same_v<T, std::uint64_t>) {
      const long long v = node.as<long long>();
      if (v < 0) throw std::invalid_argument("config key '" + key + "': must be >= 0");
      out = static_cast<std::uint64_t>(v);
    } else {
      if (!node.IsScalar()) throw std::invalid_argument("config key '" + key + "': expected a scalar");
      out = node.as<T>();
    }
  } catch (const YAML::Exception& e) {
    std::ostringstream msg;
    msg << "config key '" << key << "': cannot read '" << printable(YAML::Dump(node)) << "' as "
        << (std::is_same_v<T, bool> ? "true/false" : std::is_same_v<T, std::string> || is_named_enum_v<T> ? "text" : "a number");
    throw std::invalid_argument(msg.str());
  }
}

// The names of a mapping's keys; a key given twice is an error naming both lines (yaml-cpp keeps
// both entries and node[key] would silently take the first).
std::set<std::string> mapping_keys(const YAML::Node& map, const std::string& prefix) {
  std::map<std::string, int> first_line;
  for (const auto& kv : map) {
    if (!kv.first.IsScalar())
      throw std::invalid_argument("config: a key " + (prefix.empty() ? std::string("at the top level") : "under '" + prefix + "'") + " is not a plain name");
    const auto name = kv.first.as<std::string>();
    const int line = kv.first.Mark().line + 1;
    if (!first_line.emplace(name, line).second)
      throw std::invalid_argument("config line " + std::to_string(line) + ": duplicate key '" + prefix + printable(name) +
                                  "' (first on line " + std::to_string(first_line[name]) + ")");
  }
  std::set<std::string> keys;
  for (const auto& [name, line] : first_line) keys.insert(name);
  return keys;
}

// Throws "config line N: <what>0xNN<extra>" for the byte at `at` of `text`.
[[noreturn]] void text_error(const std::string& text, std::size_t at, const std::string& what, const std::string& extra = "") {
  const auto line = std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n') + 1;
  char byte[8];
  std::snprintf(byte, sizeof byte, "0x%02x", static_cast<unsigned char>(text[at]));
  throw std::invalid_argument("config line " + std::to_string(line) + ": " + what + byte + extra);
}

// Index of the first byte that is not part of valid UTF-8, or npos.
std::size_t first_non_utf8(const std::string& text) {
  const auto* s = reinterpret_cast<const unsigned char*>(text.data());
  const std::size_t n = text.size();
  for (std::size_t i = 0; i < n;) {
    const unsigned char c = s[i];
    std::size_t len = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
    if (len == 0 || i + len > n || (len == 2 && c < 0xC2) || (len == 4 && c > 0xF4)) return i;
    for (std::size_t k = 1; k < len; ++k)
      if ((s[i + k] & 0xC0) != 0x80) return i;
    if (len == 3) {
      const unsigned cp = ((c & 0x0Fu) << 12) | ((s[i + 1] & 0x3Fu) << 6) | (s[i + 2] & 0x3Fu);
      if (cp < 0x800 || (cp >= 0xD800 && cp <= 0xDFFF)) return i;  // overlong, surrogate
    } else if (len == 4) {
      const unsigned cp = ((c & 0x07u) << 18) | ((s[i + 1] & 0x3Fu) << 12);
      if (cp < 0x10000 || cp > 0x10FFFF) return i;
    }
    i += len;
  }
  return std::string::npos;
}

void apply_yaml(const YAML::Node& root, Config& config) {
  if (!root || root.IsNull()) return;
  if (!root.IsMap()) throw std::invalid_argument("config: the top level must be a mapping of sections");
  std::set<std::string> known_sections;
  fields::visit_sections([&](const char* name, auto section_ptr) { known_sections.insert(name); });
  for (const auto& name : mapping_keys(root, ""))
    if (!known_sections.count(name)) throw std::invalid_argument("config: unknown section '" + printable(name) + "'");
  fields::visit_sections([&](const char* section_name, auto section_ptr) {
    const YAML::Node node = root[section_name];
    if (!node || node.IsNull()) return;
    if (!node.IsMap())
      throw std::invalid_argument(std::string("config section '") + section_name + "' must be a mapping");
    auto& section = config.*section_ptr;
    std::set<std::string> known;
    fields::visit(&section, [&](const char* key, auto member, double, double, const char*) {
      known.insert(key);
      if (node[key]) read_value(node[key], std::string(section_name) + "." + key, section.*member);
    });
    for (const auto& key : mapping_keys(node, std::string(section_name) + ".")) {
      if (!known.count(key))
        throw std::invalid_argument(std::string("config: unknown key '") + section_name + "." + printable(key) + "'");
    }
  });
  validate(config);
}

template <class T> void check_range(const std::string& key, T value, double lo, double hi) {
  if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool> && !std::is_same_v<T, std::uint64_t>) {
    const double v = static_cast<double>(value);
    if (!std::isfinite(v) || v < lo || v > hi) {
      std::ostringstream msg;
      msg << "config key '" << key << "' = " << value << " is out of range [" << lo << ", " << hi << "]";
      throw std::invalid_argument(msg.str());
    }
  } else if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
    if (!value.allFinite()) throw std::invalid_argument("config key '" + key + "' has a non-finite entry");
  } else if constexpr (is_named_enum_v<T>) {
    bool named = false;
    for (const auto& n : enum_names(value)) named = named || n.value == value;
    if (!named) throw std::invalid_argument("config key '" + key + "' is not one of " + enum_choices<T>());
  }
}

}  // namespace

void validate(const Config& config) {
  fields::visit_sections([&](const char* section_name, auto section_ptr) {
    const auto& section = config.*section_ptr;
    using S = std::decay_t<decltype(section)>;
    fields::visit(static_cast<S*>(nullptr), [&](const char* key, auto member, double lo, double hi, const char*) {
      check_range(std::string(section_name) + "." + key, section.*member, lo, hi);
    });
  });
  const auto& p = config.preprocess;
  if (p.crop_enabled && !(p.crop_min_m.array() < p.crop_max_m.array()).all())
    throw std::invalid_argument("config: preprocess.crop_min_m must be below crop_max_m on every axis");
  if (config.profile.axis_direction.norm() < 1e-9)
    throw std::invalid_argument("config: profile.axis_direction must not be zero");
  if (!config.profile.alignment_path.empty() && config.profile.estimate_axis)
    throw std::invalid_argument("config: profile.alignment_path gives the axis; profile.estimate_axis would replace it (set one)");
  if (!config.profile.section_path.empty() && config.profile.estimate_axis)
    throw std::invalid_argument("config: profile.estimate_axis fits a circle and cannot be used with a design section "
                                "(profile.section_path); give the axis (profile.axis_origin_m, axis_direction)");
  if (config.grid.bay == BaySelection::range && !(config.grid.bay_start_m < config.grid.bay_end_m))
    throw std::invalid_argument("config: grid.bay is range but grid.bay_start_m = " + std::to_string(config.grid.bay_start_m) +
                                " is not below grid.bay_end_m = " + std::to_string(config.grid.bay_end_m));
  const auto& s = config.synth;
  if (s.theta_min_rad >= s.theta_max_rad)
    throw std::invalid_argument("config: synth.theta_min_rad must be below synth.theta_max_rad");
  if (s.pit_depth_min_m > s.pit_depth_max_m || s.pit_radius_min_m > s.pit_radius_max_m)
    throw std::invalid_argument("config: synth pit ranges must have min <= max");
  const auto& fl = config.flow;
  if (fl.ramp_s > fl.min_on_s || fl.ramp_s > fl.min_off_s)
    throw std::invalid_argument("config: flow.ramp_s = " + std::to_string(fl.ramp_s) +
                                " must not exceed flow.min_on_s or flow.min_off_s (ramps would overlap)");
  if (config.planner.min_speed_mps >= config.planner.max_speed_mps)
    throw std::invalid_argument("config: planner.min_speed_mps must be below planner.max_speed_mps");
}

Config config_from_yaml(const std::string& text) {
  Config config;
  if (const std::size_t bad = first_non_utf8(text); bad != std::string::npos)
    text_error(text, bad, "not UTF-8 text (byte ", ")");
  // YAML allows no C0 control characters but tab and line breaks; yaml-cpp reads a leading NUL
  // as a UTF-16/32 mark and a lone CR as part of a name.
  for (std::size_t i = 0; i < text.size(); ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    const bool lone_cr = c == '\r' && (i + 1 == text.size() || text[i + 1] != '\n');
    if ((c < 0x20 && c != '\t' && c != '\n' && c != '\r') || c == 0x7f || lone_cr)
      text_error(text, i, "control character ", std::string(lone_cr ? " (a CR without LF)" : "") + " in the text");
  }
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("config: malformed YAML: " + printable(e.what(), 200));
  }
  apply_yaml(root, config);
  return config;
}

Config load_config(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("config: cannot open '" + path + "'");
  std::stringstream buffer;
  buffer << in.rdbuf();
  try {
    return config_from_yaml(buffer.str());
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(path + ": " + e.what());
  }
}

std::string config_to_yaml(const Config& config) {
  YAML::Emitter out;
  out.SetDoublePrecision(12);  // 5.6, not 5.5999999999999996
  out << YAML::BeginMap;
  fields::visit_sections([&](const char* section_name, auto section_ptr) {
    const auto& section = config.*section_ptr;
    using S = std::decay_t<decltype(section)>;
    out << YAML::Key << section_name << YAML::Value << YAML::BeginMap;
    fields::visit(static_cast<S*>(nullptr), [&](const char* key, auto member, double, double, const char* doc) {
      const auto& v = section.*member;
      out << YAML::Key << key << YAML::Value;
      using T = std::decay_t<decltype(v)>;
      if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
        out << YAML::Flow << YAML::BeginSeq << v[0] << v[1] << v[2] << YAML::EndSeq;
      } else if constexpr (is_named_enum_v<T>) {
        out << enum_name(v);
      } else {
        out << v;
      }
      out << YAML::Comment(doc);
    });
    out << YAML::EndMap;
  });
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace shotcrete
