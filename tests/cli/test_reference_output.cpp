// Reference-image output (tools/render_references.sh): `output.half = true`
// stores the colour channels as half floats while the AOVs keep 32 bits, and
// the EXR records the command line that rendered it.
#include "engine/core/error.h"
#include "engine/image/image_io.h"
#include "engine/core/job.h"
#include "tests/support/cli_helpers.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <string>

namespace fg {
namespace {

namespace fs = std::filesystem;

fs::path scratchDirectory() { return test::scratchDirectory("reference-output"); }

TEST(ReferenceOutput, HalfIsParsedAndOffByDefault) {
    const std::string base = "scene = \"s.toml\"\npipeline = \"pt\"\n";
    EXPECT_FALSE(parseJob(base, "job.toml").output.half);
    EXPECT_TRUE(parseJob(base + "[output]\nhalf = true\n", "job.toml").output.half);
    JobOverrides overrides;
    overrides.sets = {"output.half=true"};
    EXPECT_TRUE(parseJob(base, "job.toml", overrides).output.half);
    try {
        parseJob(base + "[output]\nhalf = 1\n", "job.toml");
        FAIL() << "a number for output.half was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("job.toml:4"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("output.half"), std::string::npos) << e.what();
    }
}

TEST(ReferenceOutput, HalfExrKeepsFloatAovsAndRecordsTheCommand) {
    const fs::path dir = scratchDirectory();
    const std::string job = (fs::path(FLUXGRAPH_SOURCE_DIR) / "data" / "jobs" / "quickstart.toml").string();
    // An argument with a space and a quote, to check the recorded line quotes it for a shell.
    const std::string name = "it's ref";
    const std::string command = std::string("cd '") + dir.string() + "' && '" + FLUXGRAPH_BINARY + "' render '" + job +
                                "' --quiet --out out --set film.width=16 --set film.height=16 --set passes.pt.spp=4"
                                " --set output.half=true --set \"output.name=it's ref\" >/dev/null 2>&1";
    const int status = std::system(command.c_str());
    ASSERT_TRUE(status != -1 && WIFEXITED(status) && WEXITSTATUS(status) == 0) << command;

    const std::string exr = (dir / "out" / (name + ".exr")).string();
    {
        auto input = OIIO::ImageInput::open(exr);
        ASSERT_TRUE(input) << exr;
        const OIIO::ImageSpec& spec = input->spec();
        ASSERT_GE(spec.nchannels, 4);
        for (int c = 0; c < spec.nchannels; ++c) {
            const bool colour = c < 3;
            EXPECT_EQ(spec.channelformat(c), colour ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::FLOAT) << spec.channelnames[c];
        }
    }
    Metadata metadata;
    const ImageChannels image = readExr(exr, &metadata);
    const std::map<std::string, std::string> keys(metadata.begin(), metadata.end());
    ASSERT_TRUE(keys.count("command")) << "no command line in the metadata";
    const std::string& recorded = keys.at("command");
    EXPECT_NE(recorded.find(" render " + job + " --quiet"), std::string::npos) << recorded;
    EXPECT_NE(recorded.find("--set output.half=true"), std::string::npos) << recorded;
    EXPECT_NE(recorded.find("'output.name=it'\\''s ref'"), std::string::npos) << recorded;
    // The spp and the time are there too: in the job text, the overrides and the pass timings.
    EXPECT_NE(keys.at("overrides").find("passes.pt.spp=4"), std::string::npos);
    EXPECT_NE(keys.at("pass_timings").find("pt: wall"), std::string::npos);
    for (const auto& [channel, values] : image.extra) {
        if (channel != "time_ns") continue;
        for (float t : values) EXPECT_TRUE(std::isfinite(t) && t > 0.0f) << t;
    }
}

}  // namespace
}  // namespace fg
