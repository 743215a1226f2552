#pragma once
// Quoting user input in error messages.
#include <cstddef>
#include <string>

namespace shotcrete {

/// `text` made safe to quote in a one-line message: control and non-ASCII bytes become '?' (a raw
/// CR, LF or an invalid UTF-8 byte would break the line or the message itself), at most `max`
/// characters, then "...".
std::string printable(const std::string& text, std::size_t max = 40);

}  // namespace shotcrete
