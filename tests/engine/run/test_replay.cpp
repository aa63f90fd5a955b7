// Replay of one pass instance (engine/run/replay.h) on small versions of the
// shipped jobs: every repetition must produce the same bytes, and the same
// bytes as the pass produced inside a full render of the job; inputs saved to
// files must replay to the same outputs; bad requests are one-line InputErrors.
#include "engine/run/replay.h"

#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/core/job.h"
#include "engine/core/render.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/input_error.h"

#include <gtest/gtest.h>

#include <algorithm>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

std::string sourcePath(const std::string& relative) { return (fs::path(FLUXGRAPH_SOURCE_DIR) / relative).string(); }

fs::path scratchDirectory() { return test::scratchDirectory("replay"); }

Job smallJob(const std::string& relativePath, std::vector<std::string> sets) {
    JobOverrides overrides;
    overrides.sets = std::move(sets);
    return loadJob(sourcePath(relativePath), overrides);
}

const std::vector<std::string> kSmallSpm = {"film.width=24", "film.height=24", "passes.eye.spp=1",
                                            "passes.photon.photons=3000"};
const std::vector<std::string> kSmallPds = {"film.width=24", "film.height=24", "passes.eye.spp=1",
                                            "passes.photon.photons=20000"};
const std::vector<std::string> kSmallBre = {"film.width=16", "film.height=16", "passes.volume_eye.spp=1",
                                            "passes.photon.volume_photons=2000", "passes.photon.photons=200000"};

// The given buffers as a full render of `job` made them, encoded.
std::map<std::string, std::string> fullRunBuffers(Job job, const std::vector<std::string>& names, const fs::path& dir) {
    job.output.directory = (dir / "full").string();
    job.output.png = false;
    for (const std::string& name : names) job.bufferFiles.saves[name] = (dir / (name + ".full.fgbuf")).string();
    renderJob(job, RenderOptions{});
    std::map<std::string, std::string> encoded;
    for (const std::string& name : names)
        encoded[name] = comparableEncoding(loadBuffer((dir / (name + ".full.fgbuf")).string(), ""));
    return encoded;
}

// Replays `instance` three times and checks its outputs against a full render.
void expectReplayMatchesFullRun(const Job& job, const std::string& instance) {
    const fs::path dir = scratchDirectory();
    ReplayOptions options;
    options.instance = instance;
    options.repeat = 3;
    const ReplayResult result = replayPass(job, options);
    ASSERT_EQ(result.repetitions.size(), 3u);
    EXPECT_TRUE(result.identical()) << formatReplayReport(result);
    EXPECT_FALSE(result.inputsLoaded);
    for (const ReplayRepetition& rep : result.repetitions) {
        EXPECT_GT(rep.wallSeconds, 0.0);
        EXPECT_GE(rep.cpuSeconds, 0.0);
    }
    ASSERT_FALSE(result.outputs.empty());
    std::vector<std::string> names;
    for (const auto& [slot, version] : result.outputVersions) names.push_back(version);
    const std::map<std::string, std::string> full = fullRunBuffers(job, names, dir);
    for (const auto& [slot, version] : result.outputVersions) {
        EXPECT_TRUE(comparableEncoding(result.outputs.at(slot)) == full.at(version))
            << instance << ": output " << slot << " (" << version << ") differs from the full run's";
    }
}

TEST(Replay, PhotonPassMatchesFullRun) {
    expectReplayMatchesFullRun(smallJob("data/jobs/cornell-spm.toml", kSmallSpm), "photon");
}

TEST(Replay, GatherMatchesFullRun) {
    expectReplayMatchesFullRun(smallJob("data/jobs/cornell-spm.toml", kSmallSpm), "gather");
}

// splat reads caustic_photons in batches inside the photon pass in a render;
// the replay records those batches and hands every repetition the same ones
// (several here: 20000 photon paths in batches of 4096).
TEST(Replay, StreamedSplatMatchesFullRun) {
    // The Cornell box has no caustics; the metal ring's are splatted.
    const fs::path dir = scratchDirectory();
    const fs::path jobPath = dir / "ring-pds.toml";
    {
        std::ofstream out(jobPath);
        out << "scene = \"" << sourcePath("data/metal-ring/metal-ring.xml") << "\"\npipeline = \"pds\"\n";
    }
    JobOverrides overrides;
    overrides.sets = kSmallPds;
    overrides.sets.push_back("passes.photon.batch_size=4096");
    const Job job = loadJob(jobPath.string(), overrides);
    ReplayOptions options;
    options.instance = "splat";
    options.repeat = 1;
    const ReplayResult once = replayPass(job, options);
    ASSERT_GT(once.repetitions.at(0).items, 0) << "no caustic photons to splat";
    const auto caustics = std::find_if(once.inputs.begin(), once.inputs.end(),
                                       [](const ReplayInput& in) { return in.slot == "caustic_photons"; });
    ASSERT_NE(caustics, once.inputs.end());
    EXPECT_GT(caustics->batches, 1u) << formatReplayReport(once);
    expectReplayMatchesFullRun(job, "splat");
}

TEST(Replay, BeamQueryMatchesFullRun) {
    expectReplayMatchesFullRun(smallJob("data/spot-fog/bre.toml", kSmallBre), "beam_query");
}

TEST(Replay, PassInsideRepeatBlock) {
    const Job job = smallJob("data/jobs/progressive-pt.toml",
                             {"film.width=16", "film.height=16", "passes.pt.spp=1"});
    ReplayOptions options;
    options.instance = "progressive[2].pt";
    options.repeat = 2;
    const ReplayResult result = replayPass(job, options);
    EXPECT_TRUE(result.identical()) << formatReplayReport(result);
    ASSERT_EQ(result.inputs.size(), 1u);
    EXPECT_EQ(result.inputs[0].version, "progressive[1].image");
    EXPECT_EQ(replayInputFileName(result.inputs[0].version), "image.fgbuf");
}

TEST(Replay, SavedInputsReplayToTheSameOutputs) {
    const fs::path dir = scratchDirectory();
    const Job job = smallJob("data/jobs/cornell-spm.toml", kSmallSpm);
    ReplayOptions options;
    options.instance = "gather";
    options.repeat = 1;
    options.saveInputsDirectory = (dir / "inputs").string();
    const ReplayResult made = replayPass(job, options);
    for (const char* name : {"eye_vertices", "caustic_photons", "caustic_index", "global_photons", "global_index"})
        EXPECT_TRUE(fs::exists(dir / "inputs" / (std::string(name) + ".fgbuf"))) << name;

    options.saveInputsDirectory.clear();
    options.inputsDirectory = (dir / "inputs").string();
    options.repeat = 2;
    const ReplayResult loaded = replayPass(job, options);
    EXPECT_TRUE(loaded.inputsLoaded);
    EXPECT_TRUE(loaded.identical());
    ASSERT_EQ(loaded.outputs.size(), made.outputs.size());
    for (const auto& [slot, handle] : made.outputs)
        EXPECT_TRUE(comparableEncoding(handle) == comparableEncoding(loaded.outputs.at(slot))) << slot;
}

TEST(Replay, ReportHasARowPerRepetitionAndTheMedian) {
    ReplayResult result;
    result.instance = "gather";
    result.pass = "gather";
    result.repetitions = {{0.2, 0.4, 100}, {0.1, 0.2, 100}, {0.3, 0.6, 100}};
    const std::string report = formatReplayReport(result);
    EXPECT_NE(report.find("median          0.200000"), std::string::npos) << report;
    EXPECT_NE(report.find("outputs identical"), std::string::npos) << report;
    result.differences = {"caustic (repetition 2)"};
    EXPECT_NE(formatReplayReport(result).find("DIFFER from repetition 1's: caustic (repetition 2)"), std::string::npos);
}

std::string inputErrorOf(const Job& job, const ReplayOptions& options) {
    return test::inputErrorOf([&] { replayPass(job, options); });
}

TEST(Replay, UnknownInstanceNamesTheInstances) {
    const Job job = smallJob("data/jobs/cornell-spm.toml", kSmallSpm);
    ReplayOptions options;
    options.instance = "gahter";
    const std::string message = inputErrorOf(job, options);
    EXPECT_NE(message.find("no pass instance 'gahter'"), std::string::npos) << message;
    EXPECT_NE(message.find("eye, photon, caustic_index, global_index, gather, composite"), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos);
}

TEST(Replay, RepeatBelowOneIsRefused) {
    const Job job = smallJob("data/jobs/cornell-spm.toml", kSmallSpm);
    ReplayOptions options;
    options.instance = "gather";
    options.repeat = 0;
    EXPECT_NE(inputErrorOf(job, options).find("--repeat 0"), std::string::npos);
}

TEST(Replay, MissingInputFilesAreRefused) {
    const fs::path dir = scratchDirectory();
    const Job job = smallJob("data/jobs/cornell-spm.toml", kSmallSpm);
    ReplayOptions options;
    options.instance = "gather";
    options.inputsDirectory = (dir / "nothing-here").string();
    const std::string message = inputErrorOf(job, options);
    EXPECT_NE(message.find("eye_vertices.fgbuf"), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos);
}

// Input files are checked as validate checks imports (type, codec version,
// size) before the scene is loaded: with a scene that does not exist, a file
// cut short is what is refused, and the intact files pass on to the scene.
TEST(Replay, InputFilesAreCheckedBeforeTheSceneLoads) {
    const fs::path dir = scratchDirectory();
    Job job = smallJob("data/jobs/cornell-spm.toml", kSmallSpm);
    ReplayOptions options;
    options.instance = "gather";
    options.repeat = 1;
    options.saveInputsDirectory = (dir / "inputs").string();
    replayPass(job, options);
    options.saveInputsDirectory.clear();
    options.inputsDirectory = (dir / "inputs").string();
    job.scenePath = (dir / "no-such-scene.xml").string();
    EXPECT_NE(inputErrorOf(job, options).find("no-such-scene.xml"), std::string::npos);

    const fs::path index = dir / "inputs" / "global_index.fgbuf";
    std::string bytes;
    {
        std::ifstream in(index, std::ios::binary);
        bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    ASSERT_GT(bytes.size(), 2u);
    std::ofstream(index, std::ios::binary | std::ios::trunc).write(bytes.data(), static_cast<std::streamsize>(bytes.size() - 1));
    const std::string message = inputErrorOf(job, options);
    EXPECT_EQ(message.rfind(index.string() + ": truncated buffer file", 0), 0u) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos);
}

}  // namespace
}  // namespace fg
