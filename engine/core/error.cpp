#include "engine/core/error.h"

#include <cstddef>

namespace fg {

namespace {

// The length of the well-formed UTF-8 sequence starting at text[at], or 0 when
// the bytes there are not one (overlong forms and surrogates included, RFC 3629).
std::size_t utf8SequenceLength(std::string_view text, std::size_t at) {
    const auto byte = [&](std::size_t i) { return static_cast<unsigned char>(text[i]); };
    const unsigned char lead = byte(at);
    std::size_t length = 0;
    unsigned char secondLow = 0x80, secondHigh = 0xBF;
    if (lead < 0x80) return 1;
    if (lead >= 0xC2 && lead <= 0xDF) length = 2;
    else if (lead >= 0xE0 && lead <= 0xEF) length = 3;
    else if (lead >= 0xF0 && lead <= 0xF4) length = 4;
    else return 0;
    if (lead == 0xE0) secondLow = 0xA0;
    if (lead == 0xED) secondHigh = 0x9F;
    if (lead == 0xF0) secondLow = 0x90;
    if (lead == 0xF4) secondHigh = 0x8F;
    if (at + length > text.size()) return 0;
    if (byte(at + 1) < secondLow || byte(at + 1) > secondHigh) return 0;
    for (std::size_t i = 2; i < length; ++i)
        if (byte(at + i) < 0x80 || byte(at + i) > 0xBF) return 0;
    return length;
}

void appendEscaped(std::string& out, unsigned char c) {
    static constexpr char kHex[] = "0123456789ABCDEF";
    out += "\\x";
    out += kHex[c >> 4];
    out += kHex[c & 0xF];
}

}  // namespace

std::string printableMessage(std::string_view message) {
    std::string out;
    out.reserve(message.size());
    for (std::size_t at = 0; at < message.size();) {
        const unsigned char c = static_cast<unsigned char>(message[at]);
        const std::size_t length = utf8SequenceLength(message, at);
        // U+0080..U+009F are control characters too (a terminal may act on U+009B).
        const bool control = c < 0x20 || c == 0x7F || (length == 2 && c == 0xC2 &&
                                                       static_cast<unsigned char>(message[at + 1]) < 0xA0);
        if (length == 0) {
            appendEscaped(out, c);
            ++at;
        } else if (control) {
            for (std::size_t i = 0; i < length; ++i) appendEscaped(out, static_cast<unsigned char>(message[at + i]));
            at += length;
        } else {
            out.append(message.substr(at, length));
            at += length;
        }
    }
    return out;
}

}  // namespace fg
