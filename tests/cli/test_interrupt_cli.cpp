// Signals and memory limits against the real binary. Signals are delivered at
// exact points of a render through the FLUXGRAPH_TEST_PAUSE hook
// (engine/core/interrupt.h): the process says where it paused on stderr and
// waits for the signal. Each test asserts the exit code, the message and
// exactly which files remain.
#include "engine/image/image_io.h"

#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <signal.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

using test::CommandResult;
using test::RunningFluxgraph;
using test::sourcePath;

fs::path scratchDirectory() { return test::scratchDirectory("interrupt"); }

// Files and directories under `dir` (recursively, relative), logs excluded.
std::vector<std::string> filesUnder(const fs::path& dir) {
    std::vector<std::string> names;
    if (!fs::exists(dir)) return names;
    for (const auto& entry : fs::recursive_directory_iterator(dir)) {
        const std::string name = fs::relative(entry.path(), dir).string();
        if (name.rfind("logs", 0) != 0) names.push_back(name);
    }
    std::sort(names.begin(), names.end());
    return names;
}

// A 32 x 32 path-traced quick-start render in 16 sample passes (wave_size =
// one path per pixel: one sample per pixel per pass), written to dir/out.
std::vector<std::string> sixteenSamplePasses(std::vector<std::string> extra = {}) {
    std::vector<std::string> args = {"render", sourcePath("data/jobs/quickstart.toml"), "--out", "out"};
    for (const char* set : {"film.width=32", "film.height=32", "passes.pt.spp=16", "passes.pt.wave_size=1024"}) {
        args.push_back("--set");
        args.push_back(set);
    }
    args.insert(args.end(), extra.begin(), extra.end());
    return args;
}

// Starts `args` paused at `points`, sends `signals` one per pause (in order),
// and returns how it ended.
CommandResult signalAtPauses(const fs::path& dir, const std::vector<std::string>& args,
                             const std::vector<std::pair<std::string, int>>& pausesAndSignals) {
    std::string points;
    for (const auto& [point, signal] : pausesAndSignals) points += (points.empty() ? "" : ",") + point;
    const RunningFluxgraph process = test::startFluxgraph(dir, args, {{{"FLUXGRAPH_TEST_PAUSE", points}}, 0});
    for (const auto& [point, signal] : pausesAndSignals) {
        EXPECT_TRUE(test::waitForStderr(process, "fluxgraph-test: paused at " + point)) << point;
        ::kill(process.pid, signal);
    }
    return test::finishFluxgraph(process);
}

std::map<std::string, std::string> metadataOf(const fs::path& exr, ImageChannels* image = nullptr) {
    Metadata metadata;
    const ImageChannels read = readExr(exr.string(), &metadata);
    if (image) *image = read;
    return {metadata.begin(), metadata.end()};
}

const std::vector<float>* channel(const ImageChannels& image, const std::string& name) {
    for (const auto& [channelName, values] : image.extra)
        if (channelName == name) return &values;
    return nullptr;
}

double luminance(const Rgb& c) { return (c.x + c.y + c.z) / 3.0; }

TEST(InterruptCli, BeforeAnyUnitOfWorkNothingIsWritten) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = signalAtPauses(dir, sixteenSamplePasses(), {{"start", SIGINT}});
    EXPECT_EQ(r.exitCode, 130) << r.err;
    EXPECT_NE(r.err.find("fluxgraph: interrupted before any unit of work was done: nothing written\n"),
              std::string::npos) << r.err;
    EXPECT_EQ(filesUnder(dir), std::vector<std::string>{}) << "no output directory, no temporary";
}

TEST(InterruptCli, MidRenderTheSamplePassesDoneAreWrittenAsAPartialImage) {
    const fs::path dir = scratchDirectory();
    const CommandResult r =
        signalAtPauses(dir, sixteenSamplePasses({"--stats", "stats.json"}), {{"unit:3", SIGINT}});
    ASSERT_EQ(r.exitCode, 130) << r.err;
    EXPECT_NE(r.err.find("fluxgraph: interrupted: kept pt: 3 of 16 samples per pixel (written with "
                         "fluxgraph:partial = true)\n"),
              std::string::npos) << r.err;
    EXPECT_NE(r.out.find("wrote out/quickstart.exr"), std::string::npos) << "the pass table and files still print";
    EXPECT_EQ(filesUnder(dir), (std::vector<std::string>{"out", "out/quickstart.exr", "out/quickstart.png", "stats.json"}));
    ImageChannels partial;
    const auto metadata = metadataOf(dir / "out/quickstart.exr", &partial);
    EXPECT_EQ(metadata.at("partial"), "true");
    EXPECT_EQ(metadata.at("completed"), "pt: 3 of 16 samples per pixel");
    const std::vector<float>* samples = channel(partial, "samples");
    ASSERT_NE(samples, nullptr);
    EXPECT_TRUE(std::all_of(samples->begin(), samples->end(), [](float s) { return s == 3.0f; }));

    // The partial image estimates the same picture: its mean agrees with the
    // full render's within four standard errors (pixels as independent
    // samples: scene variation makes this bound generous, not tight). An image
    // divided by 16 samples instead of 3 would be off by a factor of five.
    const fs::path fullDir = dir / "full";
    const CommandResult full = test::runFluxgraph(fullDir, sixteenSamplePasses({"-q"}));
    ASSERT_EQ(full.exitCode, 0) << full.err;
    ImageChannels complete;
    const auto fullMetadata = metadataOf(fullDir / "out/quickstart.exr", &complete);
    EXPECT_EQ(fullMetadata.count("partial"), 0u);
    double meanPartial = 0.0, meanFull = 0.0, squares = 0.0;
    for (std::size_t i = 0; i < partial.rgb.size(); ++i) {
        meanPartial += luminance(partial.rgb[i]);
        meanFull += luminance(complete.rgb[i]);
        squares += luminance(partial.rgb[i]) * luminance(partial.rgb[i]);
    }
    const double n = static_cast<double>(partial.rgb.size());
    meanPartial /= n;
    meanFull /= n;
    const double standardError = std::sqrt(std::max(0.0, squares / n - meanPartial * meanPartial) / n);
    EXPECT_GT(meanFull, 0.0);
    EXPECT_LT(std::abs(meanPartial - meanFull), 4.0 * standardError)
        << "partial " << meanPartial << ", full " << meanFull << ", standard error " << standardError;
}

TEST(InterruptCli, AnInterruptedPhotonPassIsRenormalisedToThePathsTraced) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "lt.toml").string();
    test::writeText(job, "scene = \"" + sourcePath("data/cornell-box/cornell-box.toml") +
                             "\"\npipeline = \"lt\"\n[film]\nwidth = 16\nheight = 16\n[output]\nname = \"lt\"\n"
                             "[passes.photon]\nphotons = 100000\nbatch_size = 10000\n");
    const CommandResult r = signalAtPauses(dir, {"render", job, "--out", "out", "-q"}, {{"unit:3", SIGINT}});
    ASSERT_EQ(r.exitCode, 130) << r.err;
    EXPECT_NE(r.err.find("kept photon: 30000 of 100000 photon paths"), std::string::npos) << r.err;
    ImageChannels partial, complete;
    EXPECT_EQ(metadataOf(dir / "out/lt.exr", &partial).at("completed"), "photon: 30000 of 100000 photon paths");
    const CommandResult full = test::runFluxgraph(dir / "full", {"render", job, "--out", "out", "-q"});
    ASSERT_EQ(full.exitCode, 0) << full.err;
    metadataOf(dir / "full/out/lt.exr", &complete);
    double meanPartial = 0.0, meanFull = 0.0;
    for (std::size_t i = 0; i < partial.rgb.size(); ++i) {
        meanPartial += luminance(partial.rgb[i]);
        meanFull += luminance(complete.rgb[i]);
    }
    // 30% of the photons, streamed to the light tracer with powers for all of
    // them: without the rescale the mean would be 0.3 of the full one.
    EXPECT_NEAR(meanPartial / meanFull, 1.0, 0.1) << meanPartial << " vs " << meanFull;
}

// Each iteration of progressive-pt is two units (pt's one sample pass, then
// the finished iteration): after the fourth the block stops at 2 iterations.
TEST(InterruptCli, ARepeatBlockKeepsTheIterationsItFinished) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = signalAtPauses(
        dir,
        {"render", sourcePath("data/jobs/progressive-pt.toml"), "--out", "out", "-q", "--set", "film.width=16", "--set",
         "film.height=16"},
        {{"unit:4", SIGINT}});
    ASSERT_EQ(r.exitCode, 130) << r.err;
    EXPECT_NE(r.err.find("kept progressive: 2 of 64 iterations"), std::string::npos) << r.err;
    EXPECT_EQ(filesUnder(dir), (std::vector<std::string>{"out", "out/progressive-pt.exr", "out/progressive-pt.png"}));
    ImageChannels image;
    const auto metadata = metadataOf(dir / "out/progressive-pt.exr", &image);
    EXPECT_EQ(metadata.at("partial"), "true");
    EXPECT_EQ(metadata.at("completed"), "progressive: 2 of 64 iterations");
    EXPECT_EQ(metadata.at("iterations"), "progressive=2");
    const std::vector<float>* samples = channel(image, "samples");
    ASSERT_NE(samples, nullptr);
    EXPECT_TRUE(std::all_of(samples->begin(), samples->end(), [](float s) { return s == 32.0f; }))
        << "two iterations of 16 samples per pixel";
}

TEST(InterruptCli, DuringTheWritePhaseTheCompleteOutputsAreKept) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = signalAtPauses(dir, sixteenSamplePasses({"-q"}), {{"write", SIGINT}});
    EXPECT_EQ(r.exitCode, 130) << r.err;
    EXPECT_NE(r.err.find("fluxgraph: interrupted after the work was done: the outputs are complete\n"),
              std::string::npos) << r.err;
    EXPECT_EQ(filesUnder(dir), (std::vector<std::string>{"out", "out/quickstart.exr", "out/quickstart.png"}));
    EXPECT_EQ(metadataOf(dir / "out/quickstart.exr").count("partial"), 0u);
}

TEST(InterruptCli, ASecondInterruptQuitsAtOnceAndLeavesNothing) {
    const fs::path dir = scratchDirectory();
    const CommandResult r =
        signalAtPauses(dir, sixteenSamplePasses({"-q"}), {{"unit:3", SIGINT}, {"write", SIGINT}});
    EXPECT_EQ(r.exitCode, 130) << r.err;
    EXPECT_NE(r.err.find("fluxgraph: interrupted again: quit, nothing more written\n"), std::string::npos) << r.err;
    EXPECT_EQ(filesUnder(dir), std::vector<std::string>{}) << "temporaries and the new output directory removed";
}

TEST(InterruptCli, TerminateDuringTheWritePhaseRemovesTheTemporaries) {
    const fs::path dir = scratchDirectory();
    fs::create_directories(dir / "out");  // existing: it stays, empty
    const CommandResult r =
        signalAtPauses(dir, sixteenSamplePasses({"-q", "--stats", "out/stats.json"}), {{"write", SIGTERM}});
    EXPECT_EQ(r.exitCode, 143) << r.err;
    EXPECT_NE(r.err.find("fluxgraph: terminated (SIGTERM): nothing written\n"), std::string::npos) << r.err;
    EXPECT_EQ(filesUnder(dir), std::vector<std::string>{"out"});
}

TEST(InterruptCli, HangupMidRenderWritesNothing) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = signalAtPauses(dir, sixteenSamplePasses({"-q"}), {{"unit:3", SIGHUP}});
    EXPECT_EQ(r.exitCode, 129) << r.err;
    EXPECT_NE(r.err.find("fluxgraph: hung up (SIGHUP): nothing written\n"), std::string::npos) << r.err;
    EXPECT_EQ(filesUnder(dir), std::vector<std::string>{});
}

// --- Memory ------------------------------------------------------------------

// One line on stderr, exit 2, naming the pass, the estimate and what is
// available (and what limits it, unless `limit` is empty: MemAvailable or a
// cgroup, whichever this machine has less of).
void expectMemoryRefusal(const CommandResult& r, const std::string& pass, const std::string& limit) {
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_NE(r.err.find("pass '" + pass + "' needs about "), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(limit.empty() ? std::string("is available (") : "is available (" + limit + ")"),
              std::string::npos) << r.err;
}

constexpr long long kTwoGiB = 2ll << 30;

TEST(MemoryCli, ValidateRefusesAHugeFilmUnderAnAddressSpaceLimit) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = test::runFluxgraphWith(
        dir, {"validate", sourcePath("data/jobs/quickstart.toml"), "--set", "film.width=16384", "--set", "film.height=16384"},
        {{}, kTwoGiB});
    expectMemoryRefusal(r, "pt", "RLIMIT_AS");
    EXPECT_NE(r.err.find("film 16384 x 16384"), std::string::npos) << r.err;
}

TEST(MemoryCli, ValidateRefusesATrillionPhotonsAndPointsToStreaming) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = test::runFluxgraph(
        dir, {"validate", sourcePath("data/jobs/cornell-spm.toml"), "--set", "passes.photon.photons=1000000000000"});
    expectMemoryRefusal(r, "photon", "");
    EXPECT_NE(r.err.find("stream_batches"), std::string::npos) << r.err;
}

TEST(MemoryCli, ARenderUnderASmallAddressSpaceLimitNamesThePassAndWritesNothing) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = test::runFluxgraphWith(
        dir, {"render", sourcePath("data/jobs/cornell-spm.toml"), "--out", "out", "--set", "passes.photon.photons=40000000"},
        {{}, kTwoGiB});
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_NE(r.err.find("pass 'photon'"), std::string::npos) << r.err;
    EXPECT_EQ(r.err.find("internal error"), std::string::npos) << r.err;
    EXPECT_EQ(filesUnder(dir), std::vector<std::string>{});
}

}  // namespace
}  // namespace fg
