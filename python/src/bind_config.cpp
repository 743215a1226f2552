#include <sstream>
#include <type_traits>

#include "bindings.hpp"
#include "shotcrete/config.hpp"
#include "shotcrete/config_fields.hpp"

using namespace shotcrete;

namespace {

// Python classes for every config section, generated from the one field table.
template <class S> void bind_section(py::module_& m, const char* section_name, py::class_<Config>& config_cls,
                                     S Config::*member) {
  std::string cls_name;
  bool upper = true;
  for (const char* p = section_name; *p; ++p) {
    if (*p == '_') { upper = true; continue; }
    cls_name += upper ? static_cast<char>(std::toupper(*p)) : *p;
    upper = false;
  }
  cls_name += "Config";
  py::class_<S> cls(m, cls_name.c_str(), ("Section '" + std::string(section_name) + "' of the configuration.").c_str());
  cls.def(py::init<>());
  py::list keys;
  fields::visit(static_cast<S*>(nullptr), [&](const char* key, auto field, double lo, double hi, const char* doc) {
    using T = std::decay_t<decltype(std::declval<S>().*field)>;
    std::ostringstream d;
    d << doc;
    if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool> && !std::is_same_v<T, std::uint64_t>)
      d << "; range [" << lo << ", " << hi << "]";
    if constexpr (is_named_enum_v<T>) {
      // Enum fields are text at the Python edge, as in YAML: str in, str out ("graded"), an unknown
      // name raises ValueError listing the allowed ones.
      const std::string what = std::string(section_name) + "." + key;
      cls.def_property(
          key, [field](const S& s) { return std::string(enum_name(s.*field)); },
          [field, what](S& s, const std::string& name) { s.*field = parse_enum<T>(name, what); }, d.str().c_str());
    } else {
      cls.def_readwrite(key, field, d.str().c_str());
    }
    keys.append(key);
  });
  cls.attr("KEYS") = keys;
  config_cls.def_readwrite(section_name, member);
}

}  // namespace

void bind_config(py::module_& m) {
  py::class_<Config> config(m, "Config",
                            "The whole configuration: one attribute per section, mirroring config/default.yaml.");
  config.def(py::init<>());
  py::list sections;
  fields::visit_sections([&](const char* name, auto member) {
    bind_section(m, name, config, member);
    sections.append(name);
  });
  config.attr("SECTIONS") = sections;
  config.def("to_yaml", &config_to_yaml, "The configuration as YAML text.");
  config.def("validate", &validate, "Raise ValueError naming the first out-of-range key.");
  config.def_static("from_yaml", &config_from_yaml, py::arg("text"),
                    "Defaults overridden by YAML text; unknown keys and bad values raise ValueError.");
  config.def_static("load", &load_config, py::arg("path"), "Defaults overridden by a YAML file.");
  config.def("copy", [](const Config& c) { return Config(c); });
}
