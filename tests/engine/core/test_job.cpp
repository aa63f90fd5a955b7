#include "passes/passes.h"
#include "engine/core/job.h"

#include "engine/core/error.h"
#include "engine/core/scheduler.h"
#include "tests/support/scene_text.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <variant>
#include <vector>

namespace fg {
namespace {

using test::lineOf;

::testing::AssertionResult Contains(const std::string& text, const std::string& part) {
    if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << "'" << text << "' does not contain '" << part << "'";
}
::testing::AssertionResult BeginsWith(const std::string& text, const std::string& prefix) {
    if (text.rfind(prefix, 0) == 0) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << "'" << text << "' does not begin with '" << prefix << "'";
}

std::string parseError(const std::string& text, const JobOverrides& overrides = {}) {
    try {
        parseJob(text, "jobs/job.toml", overrides);
    } catch (const InputError& e) {
        return e.what();
    }
    ADD_FAILURE() << "parseJob accepted:\n" << text;
    return {};
}

// What a job with a mistake says, with "jobs/job.toml:LINE: " expected in front,
// LINE being where `needle` stands.
std::string at(const std::string& text, const std::string& needle) {
    return "jobs/job.toml:" + std::to_string(lineOf(text, needle)) + ": ";
}

const std::string kFullJob = R"(# A job using every section.
scene = "../scenes/box.toml"
pipeline = "pt"
seed = 7
threads = 3

[film]
width = 320
height = 200
filter = "gaussian"
filter_radius = 2.0
gaussian_sigma = 0.75

[output]
directory = "renders"
name = "box"
exr = true
png = false
exposure = -1.5

[passes.pt]
spp = 64
schedule = "tile"
)";

const std::string kMinimalJob = "scene = \"box.toml\"\npipeline = \"pt\"\n";

TEST(Job, ParsesEverySection) {
    const Job job = parseJob(kFullJob, "jobs/job.toml");
    EXPECT_EQ(job.path, "jobs/job.toml");
    EXPECT_EQ(job.text, kFullJob);
    EXPECT_EQ(job.scenePath, "scenes/box.toml");  // relative to the job file's directory
    EXPECT_EQ(job.seed, 7u);
    EXPECT_EQ(job.threads, 3);

    EXPECT_EQ(job.pipeline.name, "pt");
    ASSERT_EQ(job.pipeline.nodes.size(), 1u);
    EXPECT_EQ(job.pipeline.nodes[0].pass, "pt");
    EXPECT_EQ(job.pipeline.results, std::vector<std::string>{"image"});

    EXPECT_TRUE(job.filmSizeGiven);
    EXPECT_EQ(job.film.width, 320);
    EXPECT_EQ(job.film.height, 200);
    EXPECT_EQ(job.film.filter, FilterKind::Gaussian);
    EXPECT_EQ(job.film.filterRadius, 2.0f);
    EXPECT_EQ(job.film.gaussianSigma, 0.75f);

    EXPECT_EQ(job.output.directory, "renders");
    EXPECT_EQ(job.output.name, "box");
    EXPECT_TRUE(job.output.exr);
    EXPECT_FALSE(job.output.png);
    EXPECT_EQ(job.output.exposure, -1.5f);

    const auto& pt = job.params.values.at("pt");
    ASSERT_EQ(pt.size(), 2u);
    EXPECT_EQ(std::get<std::int64_t>(pt.at("spp").value), 64);
    EXPECT_EQ(pt.at("spp").source, "jobs/job.toml:" + std::to_string(lineOf(kFullJob, "spp = 64")));
    EXPECT_EQ(std::get<std::string>(pt.at("schedule").value), "tile");
    EXPECT_EQ(job.params.tableSource.at("pt"), "jobs/job.toml:" + std::to_string(lineOf(kFullJob, "[passes.pt]")));
    EXPECT_TRUE(job.overrides.empty());
}

TEST(Job, DefaultsForOmittedSections) {
    const Job job = parseJob(kMinimalJob, "/abs/dir/cornell.toml");
    EXPECT_EQ(job.scenePath, "/abs/dir/box.toml");
    EXPECT_EQ(job.seed, 1u);
    EXPECT_EQ(job.threads, 0);
    EXPECT_FALSE(job.filmSizeGiven);
    EXPECT_EQ(job.output.name, "cornell");  // the job file's stem
    EXPECT_EQ(job.output.directory, ".");
    EXPECT_TRUE(job.output.exr);
    EXPECT_TRUE(job.output.png);
    EXPECT_TRUE(job.params.values.empty());

    const Job box = parseJob(kMinimalJob + "[film]\nwidth = 8\nheight = 8\n", "job.toml");
    EXPECT_EQ(box.film.filter, FilterKind::Box);
    EXPECT_EQ(box.film.filterRadius, 0.5f);
}

TEST(Job, BuiltInPipelines) {
    const Pipeline* pt = findPipeline("pt");
    ASSERT_NE(pt, nullptr);
    EXPECT_EQ(pt->name, "pt");
    ASSERT_EQ(pt->nodes.size(), 1u);
    EXPECT_EQ(pt->nodes[0].instance, "pt");
    EXPECT_NE(findPass(pt->nodes[0].pass), nullptr);
    EXPECT_EQ(findPipeline("no-such-pipeline"), nullptr);
    EXPECT_EQ(findPass("no-such-pass"), nullptr);
    // Every built-in pipeline is valid as it stands.
    for (const Pipeline& p : builtinPipelines()) EXPECT_NO_THROW(ExecutionPlan::build(p, {}, "builtin")) << p.name;

    const std::string job = "scene = \"s.toml\"\npipeline = \"ptt\"\n";
    const std::string message = parseError(job);
    EXPECT_TRUE(BeginsWith(message, at(job, "ptt")));
    EXPECT_TRUE(Contains(message, "unknown pipeline 'ptt'"));
    EXPECT_TRUE(Contains(message, "built-in: ")) << message;
    EXPECT_TRUE(Contains(message, " pt,") || Contains(message, " pt)")) << message;
}

TEST(Job, UnknownKeysNameTheirLine) {
    const std::string topLevel = kMinimalJob + "colour = \"red\"\n";
    std::string message = parseError(topLevel);
    EXPECT_TRUE(BeginsWith(message, at(topLevel, "colour")));
    EXPECT_TRUE(Contains(message, "unknown key 'colour'"));
    EXPECT_TRUE(Contains(message, "scene"));  // the keys that are allowed

    const std::string inFilm = kMinimalJob + "[film]\nwidth = 8\nheight = 8\nwidht = 9\n";
    message = parseError(inFilm);
    EXPECT_TRUE(BeginsWith(message, at(inFilm, "widht")));
    EXPECT_TRUE(Contains(message, "unknown key 'film.widht'"));

    const std::string inOutput = kMinimalJob + "\n[output]\nformat = \"exr\"\n";
    EXPECT_TRUE(BeginsWith(parseError(inOutput), at(inOutput, "format")));
}

TEST(Job, MissingRequiredKeys) {
    EXPECT_TRUE(Contains(parseError("pipeline = \"pt\"\n"), "missing required key 'scene'"));
    EXPECT_TRUE(Contains(parseError("scene = \"s.toml\"\n"), "missing required key 'pipeline'"));
}

TEST(Job, MalformedTomlReportsItsLine) {
    const std::vector<std::pair<std::string, std::string>> cases = {
        {kMinimalJob + "seed = = 4\n", "seed = = 4"},
        {kMinimalJob + "\n\n[film\nwidth = 4\n", "[film"},
        {kMinimalJob + "threads = 2\nname = \"unterminated\nseed = 3\n", "unterminated"},
    };
    for (const auto& [broken, needle] : cases) {
        const int expected = lineOf(broken, needle);
        try {
            parseJob(broken, "jobs/job.toml");
            ADD_FAILURE() << "accepted:\n" << broken;
        } catch (const InputError& e) {
            EXPECT_EQ(e.line(), expected) << e.what();
            EXPECT_EQ(e.file(), "jobs/job.toml");
            EXPECT_TRUE(BeginsWith(e.what(), "jobs/job.toml:" + std::to_string(expected) + ": "));
        }
    }
}

TEST(Job, WrongValueTypes) {
    const std::string seedText = kMinimalJob + "seed = \"seven\"\n";
    EXPECT_TRUE(BeginsWith(parseError(seedText), at(seedText, "seven")));
    EXPECT_TRUE(Contains(parseError(seedText), "'seed' must be an integer"));
    const std::string pngText = kMinimalJob + "[output]\npng = 1\n";
    EXPECT_TRUE(Contains(parseError(pngText), "'output.png' must be true or false"));
    const std::string arrayParam = kMinimalJob + "[passes.pt]\nspp = [1, 2]\n";
    EXPECT_TRUE(BeginsWith(parseError(arrayParam), at(arrayParam, "spp")));
    const std::string pipelineNumber = "scene = \"s.toml\"\npipeline = 3\n";
    EXPECT_TRUE(Contains(parseError(pipelineNumber), "must be a pipeline name or a [pipeline] table"));
}

TEST(Job, SetOverridesReplaceAndAddValues) {
    JobOverrides overrides;
    overrides.sets = {"passes.pt.spp=128", "film.width=64", "seed=9", "output.name=quick"};
    const Job job = parseJob(kFullJob, "jobs/job.toml", overrides);
    const ParamSetting& spp = job.params.values.at("pt").at("spp");
    EXPECT_EQ(std::get<std::int64_t>(spp.value), 128);
    EXPECT_EQ(spp.source, "--set passes.pt.spp=128");
    EXPECT_EQ(job.film.width, 64);
    EXPECT_EQ(job.film.height, 200);  // untouched
    EXPECT_EQ(job.seed, 9u);
    EXPECT_EQ(job.output.name, "quick");  // a bare word is a string
    EXPECT_EQ(job.overrides, overrides.sets);

    // Overrides may create what the file does not have.
    JobOverrides adding;
    adding.sets = {"passes.pt.spp=8", "film.width=16", "film.height=12", "film.filter=\"gaussian\""};
    const Job added = parseJob(kMinimalJob, "jobs/job.toml", adding);
    EXPECT_EQ(std::get<std::int64_t>(added.params.values.at("pt").at("spp").value), 8);
    EXPECT_TRUE(added.filmSizeGiven);
    EXPECT_EQ(added.film.width, 16);
    EXPECT_EQ(added.film.height, 12);
    EXPECT_EQ(added.film.filter, FilterKind::Gaussian);

    // Command-line options beat the file too.
    JobOverrides options;
    options.seed = 99;
    options.threads = 1;
    options.outputDirectory = "elsewhere";
    const Job withOptions = parseJob(kFullJob, "jobs/job.toml", options);
    EXPECT_EQ(withOptions.seed, 99u);
    EXPECT_EQ(withOptions.threads, 1);
    EXPECT_EQ(withOptions.output.directory, "elsewhere");
}

TEST(Job, BadOverridesNameTheSetArgument) {
    const auto overrideError = [](const std::string& set) {
        JobOverrides overrides;
        overrides.sets = {set};
        return parseError(kFullJob, overrides);
    };
    std::string message = overrideError("film.width=wide");
    EXPECT_TRUE(BeginsWith(message, "--set film.width=wide: "));
    EXPECT_TRUE(Contains(message, "'film.width' must be an integer"));

    message = overrideError("film.width=0");
    EXPECT_TRUE(BeginsWith(message, "--set film.width=0: "));
    EXPECT_TRUE(Contains(message, "outside [1, 16384]"));

    message = overrideError("threads=-3");
    EXPECT_TRUE(BeginsWith(message, "--set threads=-3: "));

    EXPECT_TRUE(BeginsWith(overrideError("film.width"), "--set film.width: expected KEY=VALUE"));
    EXPECT_TRUE(BeginsWith(overrideError("=3"), "--set =3: expected KEY=VALUE"));
    EXPECT_TRUE(BeginsWith(overrideError("film..width=3"), "--set film..width=3: malformed key"));
    EXPECT_TRUE(BeginsWith(overrideError("seed.x=3"), "--set seed.x=3: 'seed' is not a table"));
    // A key the file does not have: the table it creates is blamed on the --set, not on the file.
    message = overrideError("bogus.key=1");
    EXPECT_TRUE(BeginsWith(message, "--set bogus.key=1: "));
    EXPECT_TRUE(Contains(message, "unknown key 'bogus'"));

    JobOverrides negative;
    negative.threads = -2;
    EXPECT_TRUE(Contains(parseError(kFullJob, negative), "--threads"));
}

TEST(Job, CustomPipeline) {
    const std::string text = R"(scene = "s.toml"

[pipeline]
name = "custom-pt"
results = ["beauty"]

[[pipeline.pass]]
pass = "pt"
name = "reference"
outputs = { image = "beauty" }

[passes.reference]
spp = 4
)";
    const Job job = parseJob(text, "jobs/job.toml");
    EXPECT_EQ(job.pipeline.name, "custom-pt");
    EXPECT_EQ(job.pipeline.results, std::vector<std::string>{"beauty"});
    ASSERT_EQ(job.pipeline.nodes.size(), 1u);
    const PipelineNode& node = job.pipeline.nodes[0];
    EXPECT_EQ(node.pass, "pt");
    EXPECT_EQ(node.instance, "reference");
    EXPECT_EQ(node.outputBindings.at("image"), "beauty");
    EXPECT_TRUE(node.inputBindings.empty());
    EXPECT_GE(node.sourceLine, lineOf(text, "[[pipeline.pass]]"));
    EXPECT_LE(node.sourceLine, lineOf(text, "pass = \"pt\""));

    const ExecutionPlan plan = ExecutionPlan::build(job.pipeline, job.params, job.path);
    ASSERT_EQ(plan.passes().size(), 1u);
    EXPECT_EQ(plan.passes()[0].params.getInt("spp"), 4);

    // A pass entry naming no registered pass fails at planning with the entry's line.
    std::string unknown = text;
    unknown.replace(unknown.find("pass = \"pt\""), 11, "pass = \"qq\"");
    const Job unknownJob = parseJob(unknown, "jobs/job.toml");
    try {
        ExecutionPlan::build(unknownJob.pipeline, unknownJob.params, unknownJob.path);
        ADD_FAILURE() << "unknown pass accepted";
    } catch (const InputError& e) {
        EXPECT_TRUE(BeginsWith(e.what(), "jobs/job.toml:" + std::to_string(unknownJob.pipeline.nodes[0].sourceLine)));
        EXPECT_TRUE(Contains(e.what(), "unknown pass 'qq'"));
    }

    const std::string noPass = "scene = \"s.toml\"\n[pipeline]\nname = \"empty\"\n";
    EXPECT_TRUE(Contains(parseError(noPass), "needs [[pipeline.pass]] entries"));
    const std::string badKey = "scene = \"s.toml\"\n[[pipeline.pass]]\npass = \"pt\"\nshape = 2\n";
    const std::string badKeyMessage = parseError(badKey);
    EXPECT_TRUE(BeginsWith(badKeyMessage, at(badKey, "shape")));
    EXPECT_TRUE(Contains(badKeyMessage, "unknown key 'pipeline.pass.shape'"));
    const std::string nameless = "scene = \"s.toml\"\n[[pipeline.pass]]\nname = \"x\"\n";
    EXPECT_TRUE(Contains(parseError(nameless), "needs 'pass = \"<registered pass>\"'"));
}

TEST(Job, FilmValidation) {
    const std::string zeroWidth = kMinimalJob + "[film]\nwidth = 0\nheight = 10\n";
    std::string message = parseError(zeroWidth);
    EXPECT_TRUE(BeginsWith(message, at(zeroWidth, "width = 0")));
    EXPECT_TRUE(Contains(message, "'film.width' = 0 is outside [1, 16384]"));

    const std::string filter = kMinimalJob + "[film]\nwidth = 4\nheight = 4\nfilter = \"mitchell\"\n";
    message = parseError(filter);
    EXPECT_TRUE(BeginsWith(message, at(filter, "mitchell")));
    EXPECT_TRUE(Contains(message, "\"mitchell\""));

    const std::string onlyWidth = kMinimalJob + "[film]\nwidth = 4\n";
    EXPECT_TRUE(Contains(parseError(onlyWidth), "give both film.width and film.height"));

    const std::string radius = kMinimalJob + "[film]\nfilter_radius = 0.0\n";
    EXPECT_TRUE(BeginsWith(parseError(radius), at(radius, "filter_radius")));
}

TEST(Job, ThreadsMustNotBeNegative) {
    const std::string inFile = kMinimalJob + "threads = -1\n";
    EXPECT_TRUE(BeginsWith(parseError(inFile), at(inFile, "threads")));
    JobOverrides overrides;
    overrides.threads = -4;
    EXPECT_TRUE(Contains(parseError(kMinimalJob, overrides), "--threads"));
    overrides.threads = 0;
    EXPECT_EQ(parseJob(kMinimalJob, "job.toml", overrides).threads, 0);
}

TEST(Job, PassParametersAreCheckedAgainstThePipeline) {
    const auto planError = [](const std::string& text) {
        const Job job = parseJob(text, "jobs/job.toml");
        try {
            ExecutionPlan::build(job.pipeline, job.params, job.path);
        } catch (const InputError& e) {
            return std::string(e.what());
        }
        ADD_FAILURE() << "planning accepted:\n" << text;
        return std::string();
    };
    const std::string negativeSpp = kMinimalJob + "\n[passes.pt]\nspp = -1\n";
    std::string message = planError(negativeSpp);
    EXPECT_TRUE(BeginsWith(message, at(negativeSpp, "spp = -1")));
    EXPECT_TRUE(Contains(message, "'pt.spp' = -1 is outside its valid range [1, 1048576]"));

    const std::string typo = kMinimalJob + "\n[passes.pt]\nsamples = 4\n";
    message = planError(typo);
    EXPECT_TRUE(BeginsWith(message, at(typo, "samples")));
    EXPECT_TRUE(Contains(message, "unknown parameter 'samples'"));

    const std::string schedule = kMinimalJob + "\n[passes.pt]\nschedule = \"spiral\"\n";
    EXPECT_TRUE(BeginsWith(planError(schedule), at(schedule, "spiral")));

    const std::string stranger = kMinimalJob + "\n[passes.photons]\ncount = 4\n";
    message = planError(stranger);
    EXPECT_TRUE(BeginsWith(message, at(stranger, "[passes.photons]")));
    EXPECT_TRUE(Contains(message, "[passes.photons] names no pass of pipeline 'pt'"));

    JobOverrides overrides;
    overrides.sets = {"passes.pt.spp=0"};
    const Job job = parseJob(kMinimalJob, "jobs/job.toml", overrides);
    try {
        ExecutionPlan::build(job.pipeline, job.params, job.path);
        ADD_FAILURE() << "spp = 0 accepted";
    } catch (const InputError& e) {
        EXPECT_TRUE(BeginsWith(e.what(), "--set passes.pt.spp=0: "));
    }
}

TEST(Job, LoadsFromAFile) {
    const std::filesystem::path dir = std::filesystem::path(FLUXGRAPH_TEST_TMP) / "job";
    std::filesystem::create_directories(dir);
    const std::filesystem::path file = dir / "render.toml";
    {
        std::ofstream out(file, std::ios::binary);
        out << kFullJob;
    }
    const Job job = loadJob(file.string());
    EXPECT_EQ(job.text, kFullJob);
    EXPECT_EQ(job.scenePath, (dir / "../scenes/box.toml").lexically_normal().string());

    try {
        loadJob((dir / "missing.toml").string());
        ADD_FAILURE() << "a missing job file loaded";
    } catch (const InputError& e) {
        EXPECT_TRUE(Contains(e.what(), "missing.toml: cannot open job file"));
    }
}

}  // namespace
}  // namespace fg
