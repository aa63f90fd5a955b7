#include "engine/core/error.h"

#include <gtest/gtest.h>

#include <string>

namespace fg {
namespace {

TEST(PrintableMessage, KeepsPrintableAsciiAndValidUtf8) {
    EXPECT_EQ(printableMessage("job.toml:3: unknown key 'x' (expected one of: a, b)"),
              "job.toml:3: unknown key 'x' (expected one of: a, b)");
    EXPECT_EQ(printableMessage("caf\xC3\xA9 4\xC3\x97" "4 \xE2\x80\xA6 \xF0\x9F\x98\x80"),
              "caf\xC3\xA9 4\xC3\x97" "4 \xE2\x80\xA6 \xF0\x9F\x98\x80");
    EXPECT_EQ(printableMessage(""), "");
}

TEST(PrintableMessage, EscapesControlCharactersSoTheMessageStaysOneLine) {
    EXPECT_EQ(printableMessage("a\x01" "b"), "a\\x01b");
    EXPECT_EQ(printableMessage("two\nlines\r"), "two\\x0Alines\\x0D");
    EXPECT_EQ(printableMessage("tab\there"), "tab\\x09here");
    EXPECT_EQ(printableMessage(std::string("nul\0!", 5)), "nul\\x00!");
    EXPECT_EQ(printableMessage("del\x7F"), "del\\x7F");
    EXPECT_EQ(printableMessage("\x1B[31mred"), "\\x1B[31mred");
    // U+009B, a one-character CSI for some terminals, is valid UTF-8 but a control.
    EXPECT_EQ(printableMessage("csi\xC2\x9B" "31m"), "csi\\xC2\\x9B31m");
    EXPECT_EQ(printableMessage("nbsp\xC2\xA0"), "nbsp\xC2\xA0");
}

TEST(PrintableMessage, EscapesEachByteOfInvalidUtf8) {
    EXPECT_EQ(printableMessage("key\xFF"), "key\\xFF");
    EXPECT_EQ(printableMessage("\xC3"), "\\xC3");                          // truncated sequence
    EXPECT_EQ(printableMessage("\xC3(x"), "\\xC3(x");                      // bad continuation
    EXPECT_EQ(printableMessage("\xC0\xAF"), "\\xC0\\xAF");                 // overlong '/'
    EXPECT_EQ(printableMessage("\xE0\x80\xAF"), "\\xE0\\x80\\xAF");        // overlong '/'
    EXPECT_EQ(printableMessage("\xED\xA0\x80"), "\\xED\\xA0\\x80");        // UTF-16 surrogate
    EXPECT_EQ(printableMessage("\xF4\x90\x80\x80"), "\\xF4\\x90\\x80\\x80");  // beyond U+10FFFF
    EXPECT_EQ(printableMessage("\x80\xA9" "ok"), "\\x80\\xA9ok");           // stray continuations
    EXPECT_EQ(printableMessage("\xE2\x80" "\xC3\xA9"), "\\xE2\\x80\xC3\xA9");  // cut short, then valid
}

}  // namespace
}  // namespace fg
