#pragma once
// Plain data types shared by every stage. SI units: metres, seconds, radians.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <functional>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "shotcrete/io/text.hpp"

namespace shotcrete {

/// Progress of a long stage: called between its steps with a stage name and the fraction done.
using ProgressFn = std::function<void(const std::string& stage, double fraction)>;

/// N x 3 row-major: maps one-to-one onto a C-contiguous numpy (N, 3) float64 array.
using Points = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// A point cloud in metres; `normals` is either empty (0 rows) or one unit normal per point.
struct Cloud {
  Points xyz;
  Points normals;

  Eigen::Index size() const { return xyz.rows(); }
  bool has_normals() const { return normals.rows() == xyz.rows() && xyz.rows() > 0; }
};

/// Nozzle pose: position and unit spray axis (roll about the axis does not matter).
struct NozzlePose {
  Eigen::Vector3d position_m{0, 0, 0};
  Eigen::Vector3d axis{0, 0, 1};
};

// ---------------------------------------------------------------------------------------------
// Named enums: the one mechanism that gives an enum its names in YAML, JSON, Python and ROS
// parameters. An enum E gets them from a function `enum_names(E)` next to it (found by
// argument-dependent lookup) returning an std::array of {value, name}; everything else is generic.

template <class E> struct EnumName {
  E value;
  const char* name;
};

template <class E, class = void> struct is_named_enum : std::false_type {};
template <class E> struct is_named_enum<E, std::void_t<decltype(enum_names(E{}))>> : std::true_type {};
template <class E> constexpr bool is_named_enum_v = is_named_enum<E>::value;

/// The name of a value ("graded"); throws std::invalid_argument for a value without one.
template <class E> const char* enum_name(E value) {
  for (const auto& n : enum_names(value))
    if (n.value == value) return n.name;
  throw std::invalid_argument("enum value " + std::to_string(static_cast<long>(value)) + " has no name");
}

/// The allowed names, comma-separated ("graded, optimal"), for messages.
template <class E> std::string enum_choices() {
  std::string list;
  for (const auto& n : enum_names(E{})) list += std::string(list.empty() ? "" : ", ") + n.name;
  return list;
}

/// The value of a name; throws std::invalid_argument "<what> = '<text>': expected one of ...".
template <class E> E parse_enum(const std::string& text, const std::string& what) {
  for (const auto& n : enum_names(E{}))
    if (text == n.name) return n.value;
  throw std::invalid_argument(what + " = '" + printable(text) + "': expected one of " + enum_choices<E>());
}

}  // namespace shotcrete
