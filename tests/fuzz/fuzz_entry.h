// Entry points shared by the libFuzzer targets (fuzz_<target>.cpp, built with
// FLUXGRAPH_FUZZ) and the replay test of the normal suite (test_fuzz_replay.cpp),
// so that every checked-in corpus and regression input runs through exactly
// the code the fuzzers ran.
//
// Each entry hands the bytes to one of fluxgraph's input paths, as
// `fluxgraph validate` would meet them: an InputError (the user's mistake,
// reported as one line and exit 2) is a refusal; any other exception escapes
// and is a finding, as are crashes, hangs and huge allocations.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>

namespace fg::fuzz {

enum class Verdict { Accepted, Refused };

using Entry = Verdict (*)(std::span<const std::uint8_t> bytes);

struct Target {
    std::string_view name;  // tests/fuzz/corpus/<name>, regressions/<name>, fuzz_<name>
    Entry entry;
};

// A job file (parseJob) and the pipeline it builds (ExecutionPlan::build).
Verdict fuzzJob(std::span<const std::uint8_t> bytes);
// A native TOML scene, through loadScene (so the scene-extent checks apply).
Verdict fuzzTomlScene(std::span<const std::uint8_t> bytes);
// A Mitsuba XML scene, through loadScene.
Verdict fuzzXmlScene(std::span<const std::uint8_t> bytes);
Verdict fuzzObj(std::span<const std::uint8_t> bytes);
Verdict fuzzPly(std::span<const std::uint8_t> bytes);
// A texture or environment map: readRgbImage, then both users of the image.
Verdict fuzzImage(std::span<const std::uint8_t> bytes);

// All of the above, by name.
std::span<const Target> targets();

}  // namespace fg::fuzz
