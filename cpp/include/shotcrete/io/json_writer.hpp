#pragma once
// A small JSON text writer for the summaries the core hands to Python, ROS and report.json, so the
// core needs no JSON library. Compact output (no whitespace), keys in the order written.
#include <string>
#include <type_traits>
#include <vector>

namespace shotcrete {

class JsonWriter {
 public:
  JsonWriter& begin_object();
  JsonWriter& end_object();
  JsonWriter& begin_array();
  JsonWriter& end_array();
  /// The key of the next value inside an object.
  JsonWriter& key(const std::string& name);

  /// A double with 17 significant digits (%.17g), so Python's json reads back the same double;
  /// integral values keep a ".0" (a float stays a float). NaN -> null; +-inf -> Infinity /
  /// -Infinity, as Python's json.dumps writes them.
  JsonWriter& value(double v);
  JsonWriter& value(bool v);
  JsonWriter& value(const std::string& v);
  JsonWriter& value(const char* v);
  template <class T, std::enable_if_t<std::is_integral_v<T> && !std::is_same_v<T, bool>, int> = 0>
  JsonWriter& value(T v) {
    return integer(static_cast<long long>(v));
  }
  JsonWriter& null();

  /// key(name) then value(v).
  template <class T>
  JsonWriter& field(const std::string& name, const T& v) {
    key(name);
    return value(v);
  }

  /// The text written so far; complete once every object and array is closed.
  const std::string& str() const { return out_; }

 private:
  JsonWriter& integer(long long v);
  void before_value();  // a comma between the elements of an array or the fields of an object
  void open(char bracket);
  void close(char bracket);

  std::string out_;
  std::vector<bool> first_;  // per open object / array: no element written yet
  bool after_key_ = false;
};

/// A JSON string literal (quotes and escapes) of UTF-8 text.
std::string json_quote(const std::string& text);

}  // namespace shotcrete
