// Text helpers for tests that write scene and job files inline and check that
// an error names the right line.
#pragma once

#include <optional>
#include <string>

namespace fg::test {

// 1-based number of the first line of `text` that contains `marker`; a missing
// marker fails the calling test and gives -1.
int lineOf(const std::string& text, const std::string& marker);

struct MitsubaSceneOptions {
    int filmSize = 32;                     // square hdrfilm, in pixels
    std::optional<double> fov = 45.0;      // nullopt leaves Mitsuba's default
    std::string version = "3.0.0";
    std::string sensor;                    // replaces the default sensor when set
};

// A Mitsuba 3 scene document around `body`, the sensor first, so that lines in
// the body are found in the whole text with lineOf.
std::string mitsubaSceneText(const std::string& body, const MitsubaSceneOptions& options = {});

}  // namespace fg::test
