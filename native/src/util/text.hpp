// Text from users' files in error messages. A message must stay one readable line of valid UTF-8: the
// Python bindings decode it strictly, and a message with an invalid byte reaches Python as an empty one.
#pragma once
#include <cstddef>
#include <cstdio>
#include <string>

namespace drapelab {

// Length of the valid UTF-8 sequence starting at s[0] (of n bytes), 0 when it is not one (RFC 3629: no
// overlong forms, no surrogates, nothing above U+10FFFF; Python's strict decoder agrees).
inline size_t utf8_sequence_length(const unsigned char* s, size_t n) {
  const unsigned c = s[0];
  if (c < 0x80) return 1;
  size_t len;
  unsigned lo = 0x80, hi = 0xbf;  // range of the second byte
  if (c >= 0xc2 && c <= 0xdf) len = 2;
  else if (c >= 0xe0 && c <= 0xef) len = 3, lo = c == 0xe0 ? 0xa0 : 0x80, hi = c == 0xed ? 0x9f : 0xbf;
  else if (c >= 0xf0 && c <= 0xf4) len = 4, lo = c == 0xf0 ? 0x90 : 0x80, hi = c == 0xf4 ? 0x8f : 0xbf;
  else return 0;
  if (n < len || s[1] < lo || s[1] > hi) return 0;
  for (size_t k = 2; k < len; ++k)
    if (s[k] < 0x80 || s[k] > 0xbf) return 0;
  return len;
}

inline bool valid_utf8(const std::string& text) {
  const auto* s = reinterpret_cast<const unsigned char*>(text.data());
  for (size_t i = 0, len; i < text.size(); i += len)
    if ((len = utf8_sequence_length(s + i, text.size() - i)) == 0) return false;
  return true;
}

// `text` for an error message: control characters and bytes that are not valid UTF-8 become \xNN, and
// text longer than `max_bytes` is cut with "...".
inline std::string printable(const std::string& text, size_t max_bytes = 80) {
  std::string out;
  const auto* s = reinterpret_cast<const unsigned char*>(text.data());
  for (size_t i = 0, len; i < text.size(); i += len) {
    if (out.size() >= max_bytes) return out + "...";
    len = utf8_sequence_length(s + i, text.size() - i);
    if (len == 0 || s[i] < 0x20 || s[i] == 0x7f) {
      char hex[8];
      std::snprintf(hex, sizeof hex, "\\x%02X", static_cast<unsigned>(s[i]));
      out += hex;
      len = 1;
    } else {
      out.append(text, i, len);
    }
  }
  return out;
}

}  // namespace drapelab
