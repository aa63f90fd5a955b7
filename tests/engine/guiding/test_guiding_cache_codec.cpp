// The guiding cache's codec version: a saved cache carries it, and a cache of
// another version (a later one, or one of the two layouts saved before the
// version was written) is refused by loadBuffer, by checkBufferFile and by
// `validate` and `render` with one line that names the file and the version,
// exit code 2 and nothing written.
#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/guiding/guiding_cache.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/input_error.h"

#include "jobs/random.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

// Records with unit normals and empty (unusable) mixtures: what the loader
// accepts, with enough bytes that a layout's size differs from another's.
std::shared_ptr<GuidingCache> smallCache() {
    jobs::Rng rng(7, jobs::streamKey("guiding-cache-codec"), 0);
    auto cache = std::make_shared<GuidingCache>();
    cache->trainingPasses = 3;
    cache->records.resize(12);
    auto positions = cache->records.column<GuidePosition>();
    auto normals = cache->records.column<GuideNormal>();
    auto radii = cache->records.column<GuideValidityRadius>();
    for (std::size_t i = 0; i < positions.size(); ++i) {
        positions[i] = Vec3(rng.uniform(), rng.uniform(), rng.uniform());
        normals[i] = Vec3(0.0f, 0.0f, 1.0f);
        radii[i] = 0.1f;
    }
    cache->rebuildIndex();
    return cache;
}

BufferHandle handleOf(const std::shared_ptr<GuidingCache>& cache) {
    BufferHandle handle;
    handle.type = BufferTypeName<GuidingCache>::value;
    handle.bytes = [raw = cache.get()] { return raw->bytes(); };
    handle.data = cache;
    return handle;
}


// Saves `cache` with `write` standing in for the builtin codec's write, as a
// build of that layout would have; the builtin codec is registered again
// whatever happens.
void saveWithLayout(const std::shared_ptr<GuidingCache>& cache, const std::string& path,
                    std::function<void(const GuidingCache&, CodecWriter&)> write) {
    registerBuiltinCodecs();
    struct Restore {
        ~Restore() {
            for (BufferCodec& codec : builtinCodecs())
                if (codec.type == BufferTypeName<GuidingCache>::value) registerCodec(std::move(codec));
        }
    } restore;
    BufferCodec stand;
    stand.type = BufferTypeName<GuidingCache>::value;
    stand.write = [write](const void* buffer, CodecWriter& writer) {
        write(*static_cast<const GuidingCache*>(buffer), writer);
    };
    stand.read = [](CodecReader& reader) -> BufferHandle { reader.fail("not read here"); };
    registerCodec(stand);
    saveBuffer(handleOf(cache), path, "# test\n");
}

// The layouts before the version was written: training passes, the records
// (without bsdf_only and moment_ratio in the first), the index.
void writeUnversioned(const GuidingCache& cache, CodecWriter& writer, bool decided) {
    const KdTree& tree = cache.tree();
    writer.setItemCount(cache.records.size());
    writer.write<std::uint64_t>(cache.trainingPasses);
    writer.writeVector("records.position", cache.records.column<GuidePosition>());
    writer.writeVector("records.normal", cache.records.column<GuideNormal>());
    writer.writeVector("records.validity_radius", cache.records.column<GuideValidityRadius>());
    writer.writeVector("records.training_radius", cache.records.column<GuideTrainingRadius>());
    writer.writeVector("records.gmm", cache.records.column<GuideMixture>());
    writer.writeVector("records.statistics", cache.records.column<GuideStatistics>());
    if (decided) {
        writer.writeVector("records.bsdf_only", cache.records.column<GuideBsdfOnly>());
        writer.writeVector("records.moment_ratio", cache.records.column<GuideMomentRatio>());
    }
    writer.write<std::uint32_t>(tree.maxLeafSize());
    writer.writeVector("tree.positions", tree.sortedPositions());
    writer.writeVector("tree.permutation", tree.permutation());
    writer.writeVector("tree.splits", tree.splits());
}

// The payload starts right after the job text.
std::size_t payloadAt(const std::string& bytes) { return bytes.find("# test\n") + std::string("# test\n").size(); }

struct CacheFiles {
    fs::path dir;
    std::string good, future, earlier, unversioned1, unversioned2;
};

// A cache as saved, the same with versions 4 and 2 written in, and the two
// layouts saved without a version.
CacheFiles makeCacheFiles(const std::string& group) {
    CacheFiles files;
    files.dir = test::scratchDirectory(group);
    registerBuiltinCodecs();
    const auto cache = smallCache();
    files.good = (files.dir / "cache.fgbuf").string();
    saveBuffer(handleOf(cache), files.good, "# test\n");
    const std::string bytes = test::readText(files.good);
    const auto withVersion = [&](std::uint32_t version, const std::string& name) {
        std::string copy = bytes;
        std::memcpy(copy.data() + payloadAt(copy), &version, sizeof version);
        test::writeText(files.dir / name, copy);
        return (files.dir / name).string();
    };
    files.future = withVersion(4, "cache-v4.fgbuf");
    files.earlier = withVersion(2, "cache-v2.fgbuf");
    files.unversioned1 = (files.dir / "cache-layout1.fgbuf").string();
    files.unversioned2 = (files.dir / "cache-layout2.fgbuf").string();
    saveWithLayout(cache, files.unversioned1,
                   [](const GuidingCache& c, CodecWriter& w) { writeUnversioned(c, w, false); });
    saveWithLayout(cache, files.unversioned2, [](const GuidingCache& c, CodecWriter& w) { writeUnversioned(c, w, true); });
    return files;
}

TEST(GuidingCacheCodec, ASavedCacheCarriesItsVersionAndLoads) {
    const CacheFiles files = makeCacheFiles("guiding-cache-codec");
    const std::string bytes = test::readText(files.good);
    std::uint32_t version = 0;
    std::memcpy(&version, bytes.data() + payloadAt(bytes), sizeof version);
    EXPECT_EQ(version, 3u);
    EXPECT_EQ(test::inputErrorOf([&] { checkBufferFile(files.good, "GuidingCache", "radiance_cache"); }), "");
    const BufferHandle loaded = loadBuffer(files.good, "GuidingCache", "radiance_cache");
    const auto& cache = *static_cast<const GuidingCache*>(loaded.data.get());
    EXPECT_EQ(cache.trainingPasses, 3u);
    EXPECT_EQ(cache.records.size(), 12u);
    // Saved again, the same bytes.
    const std::string again = (files.dir / "again.fgbuf").string();
    saveBuffer(loaded, again, "# test\n");
    EXPECT_TRUE(test::readText(again) == bytes);
}

TEST(GuidingCacheCodec, OtherVersionsAreRefusedByVersionWithOneLine) {
    const CacheFiles files = makeCacheFiles("guiding-cache-codec");
    const std::vector<std::pair<std::string, std::string>> refused = {
        {files.future, ": a guiding cache of codec version 4 (this build reads version 3)"},
        {files.earlier, ": a guiding cache of codec version 2 (this build reads version 3)"},
        {files.unversioned1, ": a guiding cache of codec version 1 (this build reads version 3), saved before the "
                             "version was written: train and save it again with this build"},
        {files.unversioned2, ": a guiding cache of codec version 2 (this build reads version 3), saved before the "
                             "version was written: train and save it again with this build"}};
    for (const auto& [file, message] : refused) {
        const std::string path = file;  // a variable, not a binding: the lambdas below capture it
        const std::string checked = test::inputErrorOf([&] { checkBufferFile(path, "GuidingCache", "radiance_cache"); });
        EXPECT_EQ(checked, path + message);
        EXPECT_EQ(test::inputErrorOf([&] { loadBuffer(path, "GuidingCache", "radiance_cache"); }), checked);
    }
}

// The job: pt on an imported cache, small, on `scene`.
std::string importingJob(const fs::path& dir,
                         const std::string& scene = test::sourcePath("data/cornell-box/cornell-box.toml")) {
    const std::string job = (dir / "imported-cache.toml").string();
    test::writeText(job, "scene = \"" + scene +
                             "\"\n[film]\nwidth = 8\nheight = 8\n[passes.pt]\nspp = 1\n"
                             "[pipeline]\nname = \"pt-on-a-cache\"\nresults = [\"image\"]\n"
                             "[[pipeline.pass]]\npass = \"pt\"\ninputs = { radiance_cache = \"radiance_cache\" }\n");
    return job;
}

TEST(GuidingCacheCodec, ValidateAndRenderRefuseOtherVersionsWithOneLine) {
    const CacheFiles files = makeCacheFiles("guiding-cache-codec-cli");
    const std::string job = importingJob(files.dir);
    const test::CommandResult good =
        test::runFluxgraph(files.dir, {"validate", job, "--import", "radiance_cache=cache.fgbuf"});
    EXPECT_EQ(good.exitCode, 0) << good.err;
    for (const std::string& path : {files.future, files.unversioned1, files.unversioned2}) {
        const std::string file = fs::path(path).filename().string();
        const std::string import = "radiance_cache=" + file;
        const test::CommandResult v = test::runFluxgraph(files.dir, {"validate", job, "--import", import});
        EXPECT_EQ(v.exitCode, 2) << file << ": " << v.err;
        EXPECT_EQ(std::count(v.err.begin(), v.err.end(), '\n'), 1) << v.err;
        EXPECT_NE(v.err.find(file + ": a guiding cache of codec version"), std::string::npos) << v.err;
        const test::CommandResult r =
            test::runFluxgraph(files.dir, {"render", job, "-q", "--out", "refused", "--import", import});
        EXPECT_EQ(r.exitCode, 2) << file << ": " << r.err;
        EXPECT_EQ(r.err, v.err);
        EXPECT_FALSE(fs::exists(files.dir / "refused"));
    }
}

// replay checks its input files (--inputs) and its imports like validate,
// before the scene loads: with a scene that does not exist, a cache of
// another version is what is refused; the cache as saved passes on to the
// scene.
TEST(GuidingCacheCodec, ReplayRefusesOtherVersionsBeforeLoadingTheScene) {
    const CacheFiles files = makeCacheFiles("guiding-cache-codec-replay");
    const std::string job = importingJob(files.dir, "no-such-scene.toml");
    fs::create_directories(files.dir / "inputs");
    fs::copy_file(files.future, files.dir / "inputs" / "radiance_cache.fgbuf");
    const std::vector<std::string> replay = {"replay", job, "--pass", "pt", "--repeat", "1"};
    const auto run = [&](std::vector<std::string> extra) {
        std::vector<std::string> args = replay;
        args.insert(args.end(), extra.begin(), extra.end());
        const test::CommandResult r = test::runFluxgraph(files.dir, args);
        EXPECT_EQ(r.exitCode, 2) << r.err;
        EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
        return r.err;
    };
    const std::string fromInputs = run({"--import", "radiance_cache=cache.fgbuf", "--inputs", "inputs"});
    EXPECT_NE(fromInputs.find((fs::path("inputs") / "radiance_cache.fgbuf").string() +
                              ": a guiding cache of codec version 4 (this build reads version 3)"),
              std::string::npos)
        << fromInputs;
    const std::string imported = run({"--import", "radiance_cache=cache-v4.fgbuf"});
    EXPECT_NE(imported.find("cache-v4.fgbuf: a guiding cache of codec version 4"), std::string::npos) << imported;
    const std::string unversioned = run({"--import", "radiance_cache=cache-layout1.fgbuf"});
    EXPECT_NE(unversioned.find("cache-layout1.fgbuf: a guiding cache of codec version 1"), std::string::npos)
        << unversioned;
    EXPECT_NE(run({"--import", "radiance_cache=cache.fgbuf"}).find("no-such-scene.toml"), std::string::npos);
}

}  // namespace
}  // namespace fg
