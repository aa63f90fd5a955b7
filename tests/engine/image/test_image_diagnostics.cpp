#include "engine/image/image_diagnostics.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdio>
#include <string>

namespace fg {
namespace {

TEST(CapturedStderr, TakesWhatWasPrintedThroughStdioAndTheDescriptor) {
    CapturedStderr captured;
    std::fprintf(stderr, "libpng error: first\n");
    const char direct[] = "second\n";
    ASSERT_EQ(write(STDERR_FILENO, direct, sizeof direct - 1), static_cast<ssize_t>(sizeof direct - 1));
    EXPECT_EQ(captured.take(), "libpng error: first\nsecond\n");
    EXPECT_EQ(captured.take(), "");
}

TEST(ImageReadFailure, JoinsLinesAndDropsThoseRepeatedInOthers) {
    CapturedStderr captured;
    std::fprintf(stderr, "libpng error: IDAT: Read error: hit end of file\n");
    EXPECT_EQ(imageReadFailure("Read error: hit end of file\nPNG read error: IDAT: Read error: hit end of file\n"
                               "PNG library error\n\nPNG library error",
                               captured),
              "PNG read error: IDAT: Read error: hit end of file; PNG library error; "
              "libpng error: IDAT: Read error: hit end of file");
}

TEST(ImageReadFailure, SaysSomethingWhenNothingWasReported) {
    CapturedStderr captured;
    EXPECT_EQ(imageReadFailure("", captured), "unknown error");
}

}  // namespace
}  // namespace fg
