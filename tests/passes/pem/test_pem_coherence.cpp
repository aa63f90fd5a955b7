// Temporal coherence of the mixture fit (Jakob et al. 2011 §5.4): the fitted
// mixture survives a save and a load byte for byte in 56 bytes per Gaussian
// (§8: about 60), and a file of another type, of the old layout, a
// truncated, a garbage or a corrupt one is refused with one line and exit
// code 2; a fit seeded from the file equals one seeded from memory; pem_fit
// seeded with the converged mixture of the same photons needs fewer EM
// iterations than the fit from its own initial guess and its F/n is at most
// 1e-3 nats per photon below that fit's; seeded fits are identical at one
// and two threads; a seed that lost components is split back to k.
#include "engine/accel/ray_query.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/core/scheduler.h"
#include "engine/gmm/em.h"
#include "engine/gmm/em_tree.h"
#include "engine/gmm/gmm_buffers.h"
#include "engine/scene/scene.h"
#include "engine/scene/scene_loader.h"
#include "jobs/parallel.h"
#include "passes/passes.h"
#include "passes/pem/pem_common.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/pass_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

BufferHandle handleOf(std::shared_ptr<GaussianMixture> mixture) {
    BufferHandle handle;
    handle.type = BufferTypeName<GaussianMixture>::value;
    handle.bytes = [raw = mixture.get()] { return raw->bytes(); };
    handle.data = std::move(mixture);
    return handle;
}

std::shared_ptr<GaussianMixture> smallMixture() {
    auto mixture = std::make_shared<GaussianMixture>();
    mixture->photons = 12345;
    mixture->components.resize(3);
    for (std::size_t s = 0; s < 3; ++s) {
        const double x = static_cast<double>(s);
        mixture->components.column<GmmWeight>()[s] = (1.0 + x) / 6.0;
        mixture->components.column<GmmPower>()[s] = glm::dvec3(0.1 * x, 0.2, 0.3 + x);
        mixture->components.column<GmmEffectiveCount>()[s] = 100.0 * (1.0 + x);
        const gmm::Sym3 covariance{{0.5 + x, 0.1, -0.05 * x, 0.7, 0.02, 0.9 + 0.1 * x}};
        setGaussianAt(mixture->components, s, gmm::Gaussian(glm::dvec3(x, -x, 0.25 * x), covariance));
    }
    // As the fits hand a mixture on (storeMixture).
    EXPECT_TRUE(roundToStored(mixture->components));
    return mixture;
}

// Every column of two mixtures, derived ones included, bit for bit.
void expectSameMixture(const GmmBuffer& a, const GmmBuffer& b) {
    ASSERT_EQ(a.size(), b.size());
    const std::size_t n = a.size();
    EXPECT_EQ(std::memcmp(a.column<GmmWeight>().data(), b.column<GmmWeight>().data(), n * sizeof(double)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmPower>().data(), b.column<GmmPower>().data(), n * sizeof(glm::dvec3)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmMean>().data(), b.column<GmmMean>().data(), n * sizeof(glm::dvec3)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmCovariance>().data(), b.column<GmmCovariance>().data(), n * sizeof(gmm::Sym3)),
              0);
    EXPECT_EQ(std::memcmp(a.column<GmmCholesky>().data(), b.column<GmmCholesky>().data(), n * sizeof(gmm::Sym3)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmPrecision>().data(), b.column<GmmPrecision>().data(), n * sizeof(gmm::Sym3)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmLogNormaliser>().data(), b.column<GmmLogNormaliser>().data(), n * sizeof(double)),
              0);
    EXPECT_EQ(
        std::memcmp(a.column<GmmEffectiveCount>().data(), b.column<GmmEffectiveCount>().data(), n * sizeof(double)), 0);
}

TEST(PemCoherence, MixtureRoundTripsByteForByte) {
    const fs::path dir = test::scratchDirectory("pem-coherence");
    registerBuiltinCodecs();
    const auto original = smallMixture();
    saveBuffer(handleOf(original), (dir / "first.fgbuf").string(), "# test\n");
    const BufferHandle loaded = loadBuffer((dir / "first.fgbuf").string(), "GaussianMixture", "gmm");
    ASSERT_EQ(loaded.type, "GaussianMixture");
    saveBuffer(loaded, (dir / "second.fgbuf").string(), "# test\n");
    EXPECT_EQ(test::readText(dir / "first.fgbuf"), test::readText(dir / "second.fgbuf"));
    const GaussianMixture& back = test::bufferAs<GaussianMixture>(loaded);
    EXPECT_EQ(back.photons, 12345u);
    ASSERT_EQ(back.components.size(), 3u);
    expectSameMixture(back.components, original->components);
}

// Rounding to the stored form moves a component by single-precision
// rounding only, and the derived columns are those of the rounded factor.
TEST(PemCoherence, RoundingToTheStoredFormMovesParametersByFloatRounding) {
    GmmBuffer exact(1);
    exact.column<GmmWeight>()[0] = 0.3;
    exact.column<GmmPower>()[0] = glm::dvec3(0.7, 1.1, 1.3);
    exact.column<GmmEffectiveCount>()[0] = 1234.5678;
    const gmm::Sym3 covariance{{0.02, 0.004, -0.001, 0.03, 0.002, 0.01}};
    setGaussianAt(exact, 0, gmm::Gaussian(glm::dvec3(1.1, -2.3, 0.7), covariance));
    GmmBuffer rounded(1);
    ASSERT_TRUE(expandStoredComponent(storedComponent(exact, 0), rounded, 0));
    const auto close = [](double a, double b, double relative) { return std::abs(a - b) <= relative * std::abs(b); };
    EXPECT_TRUE(close(rounded.column<GmmWeight>()[0], 0.3, 6e-8));
    for (int a = 0; a < 3; ++a)
        EXPECT_TRUE(close(rounded.column<GmmMean>()[0][a], exact.column<GmmMean>()[0][a], 6e-8));
    // Sigma_ij = sum_k L_ik L_jk with each factor off by at most 6e-8 of itself.
    const double largestVariance = 0.03;
    for (std::size_t e = 0; e < 6; ++e)
        EXPECT_NEAR(rounded.column<GmmCovariance>()[0].v[e], covariance.v[e], 1.2e-7 * largestVariance);
    const gmm::GaussianFactors refactored = gmm::factorise(rounded.column<GmmCovariance>()[0]);
    for (std::size_t e = 0; e < 6; ++e)
        EXPECT_NEAR(rounded.column<GmmPrecision>()[0].v[e], refactored.precision.v[e],
                    1e-12 * refactored.precision.v[0]);
    EXPECT_NEAR(rounded.column<GmmLogNormaliser>()[0], refactored.logNormaliser, 1e-12);
    EXPECT_TRUE(close(rounded.column<GmmLogNormaliser>()[0], exact.column<GmmLogNormaliser>()[0], 1e-6));
    // Rounding twice changes nothing.
    GmmBuffer twice(1);
    ASSERT_TRUE(expandStoredComponent(storedComponent(rounded, 0), twice, 0));
    expectSameMixture(twice, rounded);
}

// §8: "a GMM with 4096 terms requires about 240 KB" (about 60 bytes per
// Gaussian). The file holds 56 per Gaussian and a header of fixed size.
TEST(PemCoherence, ASavedMixtureTakesFiftySixBytesPerGaussian) {
    const fs::path dir = test::scratchDirectory("pem-coherence");
    registerBuiltinCodecs();
    std::vector<std::uintmax_t> sizes;
    for (const std::size_t k : {std::size_t{1024}, std::size_t{4096}}) {
        auto mixture = std::make_shared<GaussianMixture>();
        mixture->photons = 128 * k;
        mixture->components.resize(k);
        for (std::size_t s = 0; s < k; ++s) {
            const double x = static_cast<double>(s) / static_cast<double>(k);
            mixture->components.column<GmmWeight>()[s] = 1.0 / static_cast<double>(k);
            mixture->components.column<GmmPower>()[s] = glm::dvec3(x, 1.0 - x, 0.5);
            mixture->components.column<GmmEffectiveCount>()[s] = 128.0 + x;
            setGaussianAt(mixture->components, s,
                          gmm::Gaussian(glm::dvec3(x, x * x, 1.0 - x), gmm::Sym3{{0.01, 0.001, 0.0, 0.02, 0.0, 0.03}}));
        }
        ASSERT_TRUE(roundToStored(mixture->components));
        const fs::path path = dir / ("k" + std::to_string(k) + ".fgbuf");
        saveBuffer(handleOf(mixture), path.string(), "# test\n");
        sizes.push_back(fs::file_size(path));
        std::printf("k = %zu: %ju bytes, %.2f per Gaussian\n", k, sizes.back(),
                    static_cast<double>(sizes.back()) / static_cast<double>(k));
        EXPECT_LE(sizes.back(), 60 * k);
    }
    EXPECT_EQ(sizes[1] - sizes[0], 56u * (4096 - 1024));
}

// The codec version is the first scalar of the payload, right after the job
// text; a component that is not a usable Gaussian is refused on loading.
TEST(PemCoherence, OtherCodecVersionsAndCorruptComponentsAreRefused) {
    const fs::path dir = test::scratchDirectory("pem-coherence");
    registerBuiltinCodecs();
    const std::string path = (dir / "gmm.fgbuf").string();
    saveBuffer(handleOf(smallMixture()), path, "# test\n");
    const std::string bytes = test::readText(path);
    const std::size_t version = bytes.find("# test\n") + std::string("# test\n").size();
    ASSERT_EQ(bytes[version], '\x02');
    std::string other = bytes;
    other[version] = '\x03';
    test::writeText(dir / "version.fgbuf", other);
    EXPECT_THROW(loadBuffer((dir / "version.fgbuf").string(), "GaussianMixture", "gmm"), InputError);

    auto broken = smallMixture();
    broken->components.column<GmmMean>()[1].y = std::numeric_limits<double>::quiet_NaN();
    saveBuffer(handleOf(broken), (dir / "nan.fgbuf").string(), "# test\n");
    EXPECT_THROW(loadBuffer((dir / "nan.fgbuf").string(), "GaussianMixture", "gmm"), InputError);
    auto singular = smallMixture();
    singular->components.column<GmmCholesky>()[2].v[3] = 0.0;
    saveBuffer(handleOf(singular), (dir / "singular.fgbuf").string(), "# test\n");
    EXPECT_THROW(loadBuffer((dir / "singular.fgbuf").string(), "GaussianMixture", "gmm"), InputError);
}

TEST(PemCoherence, BadMixtureFilesAreRefusedWithOneLineBeforeAnyWork) {
    const fs::path dir = test::scratchDirectory("pem-coherence");
    registerBuiltinCodecs();
    saveBuffer(handleOf(smallMixture()), (dir / "gmm.fgbuf").string(), "# test\n");
    auto photons = std::make_shared<VolumePhotonMap>();
    photons->emitted = 3;
    photons->photons.resize(2);
    BufferHandle other;
    other.type = BufferTypeName<VolumePhotonMap>::value;
    other.bytes = [raw = photons.get()] { return raw->bytes(); };
    other.data = photons;
    saveBuffer(other, (dir / "photons.fgbuf").string(), "# test\n");
    const std::string mixture = test::readText(dir / "gmm.fgbuf");
    test::writeText(dir / "half.fgbuf", mixture.substr(0, mixture.size() / 2));
    // The header is intact and only the payload's last bytes are missing:
    // the file's size tells, so validate refuses it too.
    test::writeText(dir / "short.fgbuf", mixture.substr(0, mixture.size() - 9));
    test::writeText(dir / "garbage.fgbuf", "FGBUF and then nothing that makes sense");
    const std::string job = test::sourcePath("data/spot-fog/pem.toml");
    const test::CommandResult good = test::runFluxgraph(dir, {"validate", job, "--import", "previous_gmm=gmm.fgbuf"});
    EXPECT_EQ(good.exitCode, 0) << good.err;
    const auto expectRefused = [&](const std::vector<std::string>& args, const std::string& file) {
        const test::CommandResult r = test::runFluxgraph(dir, args);
        EXPECT_EQ(r.exitCode, 2) << file << ": " << r.err;
        EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
        EXPECT_NE(r.err.find(file), std::string::npos) << r.err;
        EXPECT_FALSE(fs::exists(dir / "refused"));
    };
    for (const std::string file : {"photons.fgbuf", "half.fgbuf", "garbage.fgbuf", "short.fgbuf"}) {
        const std::string import = "previous_gmm=" + file;
        expectRefused({"validate", job, "--import", import}, file);
        expectRefused({"render", job, "-q", "--out", "refused", "--import", import}, file);
    }
}

const Scene& spotFog() {
    static const Scene scene = loadScene(test::sourcePath("data/spot-fog/spot-fog.xml"), {});
    return scene;
}

struct Fit {
    std::shared_ptr<GaussianMixture> mixture;
    std::vector<double> parameters;
    std::map<std::string, std::int64_t> counters;
    double boundPerPhoton() const { return static_cast<double>(counters.at("bound_per_photon_e6")) * 1e-6; }
};

// photon -> pem_fit (k = 32, n0 = 4096, maps of 1024), optionally seeded with
// `previous` the way `--import previous_gmm=...` hands it over.
Fit runFit(int threads, const std::shared_ptr<GaussianMixture>& previous, std::int64_t maxPhotons = 0) {
    Pipeline pipeline;
    pipeline.name = "pem_fit";
    PipelineNode photon;
    photon.instance = photon.pass = "photon";
    PipelineNode fit;
    fit.instance = fit.pass = "pem_fit";
    fit.inputBindings["photons"] = "volume_photons";
    fit.inputBindings["previous"] = "previous_gmm";
    pipeline.nodes = {photon, fit};
    pipeline.results = {"gmm"};
    JobParams params;
    params.values["photon"]["photons"] = {std::int64_t{100000000}, "test"};
    params.values["photon"]["volume_photons"] = {std::int64_t{4096}, "test"};
    params.values["photon"]["volume_batch"] = {std::int64_t{1024}, "test"};
    params.values["pem_fit"]["k"] = {std::int64_t{32}, "test"};
    params.values["pem_fit"]["max_photons"] = {maxPhotons, "test"};
    BufferFiles files;
    RunOptions options;
    if (previous) {
        files.imports["previous_gmm"] = "previous.fgbuf";
        options.imported["previous_gmm"] = handleOf(previous);
    }
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, params, "test", passRegistry(), files);
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(spotFog());
    const RunResult run = execute(plan, spotFog(), &rays, options);
    Fit out;
    out.mixture = std::static_pointer_cast<GaussianMixture>(run.results.at("gmm").data);
    const GmmBuffer& gmm = out.mixture->components;
    for (std::size_t s = 0; s < gmm.size(); ++s) {
        out.parameters.push_back(gmm.column<GmmWeight>()[s]);
        for (int i = 0; i < 3; ++i) out.parameters.push_back(gmm.column<GmmMean>()[s][i]);
        for (int i = 0; i < 3; ++i) out.parameters.push_back(gmm.column<GmmPower>()[s][i]);
        for (const double v : gmm.column<GmmCovariance>()[s].v) out.parameters.push_back(v);
    }
    for (const PassStats& s : run.stats)
        if (s.pass == "pem_fit") out.counters = s.counters;
    out.counters.erase("fit_us");  // wall time
    return out;
}

// The first 4096 volume photons, as the stream's first map holds them.
std::shared_ptr<VolumePhotonMap> firstPhotons() {
    Pipeline pipeline;
    pipeline.name = "photons";
    PipelineNode photon;
    photon.instance = photon.pass = "photon";
    pipeline.nodes = {photon};
    pipeline.results = {"volume_photons"};
    JobParams params;
    params.values["photon"]["photons"] = {std::int64_t{100000000}, "test"};
    params.values["photon"]["volume_photons"] = {std::int64_t{4096}, "test"};
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, params, "test");
    const RayQuery rays(spotFog());
    const RunResult run = execute(plan, spotFog(), &rays, RunOptions{});
    return std::static_pointer_cast<VolumePhotonMap>(run.results.at("volume_photons").data);
}

// F/n (Eq. 8) of a mixture on the leaves of the statistics tree over these
// photons, all cell-component pairs: one partition for every mixture
// compared, unlike the bound each fit reports on its own final cut.
double boundOnLeaves(const VolumePhotonMap& photons, const GaussianMixture& mixture) {
    EmTree tree;
    tree.build(photons.photons.column<PhotonPosition>(), photons.photons.column<PhotonPower>(), 4);
    const gmm::EmCells cells = cellsOf(tree, tree.cut(tree.size()));
    std::vector<gmm::EmComponent> components;
    for (std::size_t s = 0; s < mixture.components.size(); ++s) {
        gmm::EmComponent c;
        c.weight = mixture.components.column<GmmWeight>()[s];
        c.gaussian = gaussianAt(mixture.components, s);
        components.push_back(c);
    }
    gmm::Responsibilities q;
    return gmm::eStep(cells, components, 0.0, q) / cells.totalCount();
}

// Seeded with the converged mixture of the same photons (no later maps, so
// both fits see exactly the first map's), the fit starts near its solution:
// fewer EM iterations, and on one partition an F/n no more than 1e-3 nats
// per photon below the independent fit's. (The bounds the fits report are
// on their own final cuts; the seeded fit's is finer, and a finer cut alone
// raises F.) Here the seeded fit is the independent one refined further, on
// the leaves 0.008 nats per photon above it.
TEST(PemCoherence, SeededWithTheConvergedMixtureItNeedsFewerIterationsForTheSameBound) {
    const Fit independent = runFit(2, nullptr, 4096);
    ASSERT_FALSE(independent.parameters.empty());
    EXPECT_EQ(independent.counters.at("seeded"), 0);
    const Fit seeded = runFit(2, independent.mixture, 4096);
    EXPECT_EQ(seeded.counters.at("seeded"), 1);
    EXPECT_EQ(seeded.counters.at("photons"), 4096);
    EXPECT_EQ(seeded.counters.at("components"), independent.counters.at("components"));
    EXPECT_LT(seeded.counters.at("inner_iterations"), independent.counters.at("inner_iterations"));
    const std::shared_ptr<VolumePhotonMap> photons = firstPhotons();
    const double independentBound = boundOnLeaves(*photons, *independent.mixture);
    const double seededBound = boundOnLeaves(*photons, *seeded.mixture);
    EXPECT_GE(seededBound, independentBound - 1e-3);
    std::printf("independent: %lld inner / %lld outer iterations, |P| %lld, F/n %.6f (on the leaves %.6f); seeded: "
                "%lld / %lld, |P| %lld, F/n %.6f (on the leaves %.6f)\n",
                static_cast<long long>(independent.counters.at("inner_iterations")),
                static_cast<long long>(independent.counters.at("outer_iterations")),
                static_cast<long long>(independent.counters.at("cells")), independent.boundPerPhoton(),
                independentBound, static_cast<long long>(seeded.counters.at("inner_iterations")),
                static_cast<long long>(seeded.counters.at("outer_iterations")),
                static_cast<long long>(seeded.counters.at("cells")), seeded.boundPerPhoton(), seededBound);
}

// A file of the first layout (every column in doubles, derived ones
// included, codec version 1) is refused by render and by validate with one
// line that names the file and the layout, exit code 2.
TEST(PemCoherence, OldLayoutFilesAreRefusedWithOneLine) {
    const fs::path dir = test::scratchDirectory("pem-coherence");
    registerBuiltinCodecs();
    BufferCodec old;
    old.type = BufferTypeName<GaussianMixture>::value;
    old.write = [](const void* buffer, CodecWriter& writer) {
        const auto& mixture = *static_cast<const GaussianMixture*>(buffer);
        writer.setItemCount(mixture.components.size());
        writer.write<std::uint32_t>(1);
        writer.write<std::uint64_t>(mixture.photons);
        writer.writeSoa("components", mixture.components);
    };
    old.read = [](CodecReader& reader) -> BufferHandle { reader.fail("not read here"); };
    registerCodec(old);
    saveBuffer(handleOf(smallMixture()), (dir / "old.fgbuf").string(), "# test\n");
    for (const BufferCodec& codec : builtinCodecs())
        if (codec.type == old.type) registerCodec(codec);
    EXPECT_THROW(loadBuffer((dir / "old.fgbuf").string(), "GaussianMixture", "gmm"), InputError);
    const std::string job = test::sourcePath("data/spot-fog/pem.toml");
    const test::CommandResult r =
        test::runFluxgraph(dir, {"render", job, "-q", "--out", "refused", "--import", "previous_gmm=old.fgbuf"});
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_NE(r.err.find("old.fgbuf"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("codec version 1"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir / "refused"));
    const test::CommandResult v = test::runFluxgraph(dir, {"validate", job, "--import", "previous_gmm=old.fgbuf"});
    EXPECT_EQ(v.exitCode, 2) << v.err;
    EXPECT_EQ(v.err, r.err);
}

// The codec version is the first scalar of the payload, after the header:
// validate reads it too, so a mixture or a pyramid file that render refuses
// on loading for its codec version is refused by validate with the same line
// and exit code 2, before any work; the files as saved pass both.
TEST(PemCoherence, ValidateRefusesTheCodecVersionsRenderRefuses) {
    const fs::path dir = test::scratchDirectory("pem-coherence-versions");
    registerBuiltinCodecs();
    FilmSettings film;
    film.width = film.height = 4;
    const auto pyramid =
        test::runPass(*findPass("gmm_pyramid"), spotFog(), nullptr, film, {{"gmm", handleOf(smallMixture())}});
    ASSERT_EQ(pyramid.count("pyramid"), 1u);
    ASSERT_GT(test::bufferAs<GmmPyramid>(pyramid.at("pyramid")).nodes.size(), 1u);
    saveBuffer(handleOf(smallMixture()), (dir / "gmm.fgbuf").string(), "# test\n");
    saveBuffer(pyramid.at("pyramid"), (dir / "pyramid.fgbuf").string(), "# test\n");
    const auto withVersion = [&](const std::string& from, const std::string& to, char expected, char version) {
        std::string bytes = test::readText(dir / from);
        const std::size_t at = bytes.find("# test\n") + std::string("# test\n").size();
        ASSERT_EQ(bytes[at], expected) << from;
        bytes[at] = version;
        test::writeText(dir / to, bytes);
    };
    withVersion("gmm.fgbuf", "gmm-v1.fgbuf", '\x02', '\x01');
    withVersion("gmm.fgbuf", "gmm-v3.fgbuf", '\x02', '\x03');
    withVersion("pyramid.fgbuf", "pyramid-v2.fgbuf", '\x01', '\x02');

    const std::string job = test::sourcePath("data/spot-fog/pem.toml");
    const test::CommandResult good = test::runFluxgraph(
        dir, {"validate", job, "--import", "previous_gmm=gmm.fgbuf", "--import", "gmm_pyramid=pyramid.fgbuf"});
    EXPECT_EQ(good.exitCode, 0) << good.err;

    const std::vector<std::pair<std::string, std::string>> refused = {
        {"previous_gmm=gmm-v1.fgbuf", "codec version 1 (doubles with derived columns)"},
        {"previous_gmm=gmm-v3.fgbuf", "a Gaussian mixture of codec version 3 (this build reads version 2)"},
        {"gmm_pyramid=pyramid-v2.fgbuf", "a Gaussian pyramid of codec version 2 (this build reads version 1)"}};
    for (const auto& [import, message] : refused) {
        const std::string file = import.substr(import.find('=') + 1);
        const test::CommandResult v = test::runFluxgraph(dir, {"validate", job, "--import", import});
        EXPECT_EQ(v.exitCode, 2) << import << ": " << v.err;
        EXPECT_EQ(std::count(v.err.begin(), v.err.end(), '\n'), 1) << v.err;
        EXPECT_NE(v.err.find(file + ": "), std::string::npos) << v.err;
        EXPECT_NE(v.err.find(message), std::string::npos) << v.err;
        const test::CommandResult r =
            test::runFluxgraph(dir, {"render", job, "-q", "--out", "refused", "--import", import});
        EXPECT_EQ(r.exitCode, 2) << import << ": " << r.err;
        EXPECT_EQ(v.err, r.err);
        EXPECT_FALSE(fs::exists(dir / "refused"));
    }
}

// The coherent fit (§5.4) through a file: the next frame seeded from the
// saved and loaded mixture is the one seeded from the mixture in memory.
TEST(PemCoherence, AFitSeededFromTheFileEqualsOneSeededFromMemory) {
    const fs::path dir = test::scratchDirectory("pem-coherence");
    registerBuiltinCodecs();
    const Fit previous = runFit(2, nullptr);
    ASSERT_FALSE(previous.parameters.empty());
    const std::string path = (dir / "previous.fgbuf").string();
    saveBuffer(handleOf(previous.mixture), path, "# test\n");
    const auto loaded = std::static_pointer_cast<GaussianMixture>(loadBuffer(path, "GaussianMixture", "gmm").data);
    expectSameMixture(loaded->components, previous.mixture->components);
    const Fit fromMemory = runFit(2, previous.mixture);
    const Fit fromFile = runFit(2, loaded);
    ASSERT_EQ(fromMemory.parameters.size(), fromFile.parameters.size());
    EXPECT_EQ(std::memcmp(fromMemory.parameters.data(), fromFile.parameters.data(),
                          fromMemory.parameters.size() * sizeof(double)),
              0);
    EXPECT_EQ(fromMemory.counters, fromFile.counters);
}

// With photons on demand the seeded fit is the same at one and two threads,
// bit for bit, and differs from the unseeded one (the seed is used).
TEST(PemCoherence, SeededFitsAreIdenticalAtOneAndTwoThreads) {
    const Fit previous = runFit(2, nullptr);
    const Fit one = runFit(1, previous.mixture);
    const Fit two = runFit(2, previous.mixture);
    ASSERT_FALSE(one.parameters.empty());
    ASSERT_EQ(one.parameters.size(), two.parameters.size());
    EXPECT_EQ(std::memcmp(one.parameters.data(), two.parameters.data(), one.parameters.size() * sizeof(double)), 0);
    EXPECT_EQ(one.counters, two.counters);
    EXPECT_EQ(one.counters.at("seeded"), 1);
    EXPECT_NE(one.parameters, previous.parameters);
}


// The seed's first and second moments: total weight, sum w mu and
// sum w (Sigma + mu mu^T).
struct SeedMoments {
    double weight = 0.0;
    glm::dvec3 first{0.0};
    gmm::Sym3 second;
};
SeedMoments momentsOf(const std::vector<gmm::EmComponent>& components) {
    SeedMoments m;
    for (const gmm::EmComponent& c : components) {
        m.weight += c.weight;
        m.first += c.weight * c.gaussian.mean;
        m.second += (c.gaussian.covariance + gmm::Sym3::outer(c.gaussian.mean)) * c.weight;
    }
    return m;
}

std::vector<gmm::EmComponent> componentsOf(const GaussianMixture& mixture) {
    std::vector<gmm::EmComponent> components;
    for (std::size_t s = 0; s < mixture.components.size(); ++s) {
        gmm::EmComponent c;
        c.weight = mixture.components.column<GmmWeight>()[s];
        c.power = mixture.components.column<GmmPower>()[s];
        c.effectiveCount = mixture.components.column<GmmEffectiveCount>()[s];
        c.gaussian = gaussianAt(mixture.components, s);
        components.push_back(c);
    }
    return components;
}

// A seed that lost components is completed to k by splits that keep the
// seed's weight and moments (1e-12) and give usable Gaussians, the same way
// every time; a seed of k components is left byte for byte as it is.
TEST(PemCoherence, SplittingCompletesASeedToKComponentsAndKeepsItsMoments) {
    const Fit previous = runFit(2, nullptr);
    const std::vector<gmm::EmComponent> full = componentsOf(*previous.mixture);
    const std::size_t k = full.size();
    ASSERT_GE(k, 16u);

    std::vector<gmm::EmComponent> untouched = full;
    EXPECT_EQ(splitToCount(untouched, k), 0u);
    ASSERT_EQ(untouched.size(), k);
    for (std::size_t s = 0; s < k; ++s) {
        EXPECT_EQ(std::memcmp(&untouched[s].weight, &full[s].weight, sizeof(double)), 0);
        EXPECT_EQ(std::memcmp(&untouched[s].gaussian.mean, &full[s].gaussian.mean, sizeof(glm::dvec3)), 0);
        EXPECT_EQ(std::memcmp(untouched[s].gaussian.covariance.v.data(), full[s].gaussian.covariance.v.data(),
                              sizeof(full[s].gaussian.covariance.v)),
                  0);
    }

    std::vector<gmm::EmComponent> reduced;
    for (std::size_t s = 0; s < k; ++s)
        if (s % 5 != 2) reduced.push_back(full[s]);
    const std::size_t removed = k - reduced.size();
    const SeedMoments before = momentsOf(reduced);
    std::vector<gmm::EmComponent> once = reduced, twice = reduced;
    EXPECT_EQ(splitToCount(once, k), removed);
    EXPECT_EQ(splitToCount(twice, k), removed);
    ASSERT_EQ(once.size(), k);
    ASSERT_EQ(twice.size(), k);
    for (std::size_t s = 0; s < k; ++s) {
        EXPECT_EQ(std::memcmp(&once[s].weight, &twice[s].weight, sizeof(double)), 0);
        EXPECT_EQ(std::memcmp(&once[s].gaussian.mean, &twice[s].gaussian.mean, sizeof(glm::dvec3)), 0);
        EXPECT_TRUE(once[s].gaussian.factors.valid) << s;
        EXPECT_GT(once[s].weight, 0.0);
    }
    const SeedMoments after = momentsOf(once);
    const double scale = std::max(1.0, std::abs(before.second.trace()));
    EXPECT_NEAR(after.weight, before.weight, 1e-12);
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(after.first[i], before.first[i], 1e-12 * scale);
    for (std::size_t e = 0; e < 6; ++e) EXPECT_NEAR(after.second.v[e], before.second.v[e], 1e-12 * scale);
    // Only split components move; the others keep their places and values.
    std::size_t unchanged = 0;
    for (std::size_t s = 0; s < reduced.size(); ++s)
        unchanged += std::memcmp(&once[s].gaussian.mean, &reduced[s].gaussian.mean, sizeof(glm::dvec3)) == 0 ? 1 : 0;
    EXPECT_GE(unchanged, reduced.size() - removed);
}

// pem_fit seeded with a mixture that lost components fits k again (none is
// dropped at these photon counts), the same at one and two threads; seeded
// with all k it restores none.
TEST(PemCoherence, ASeedWithComponentsRemovedGetsBackToK) {
    const Fit previous = runFit(2, nullptr);
    const std::int64_t k = 32;
    ASSERT_EQ(previous.counters.at("components"), k);
    const GmmBuffer& from = previous.mixture->components;
    auto reduced = std::make_shared<GaussianMixture>();
    reduced->photons = previous.mixture->photons;
    reduced->components.resize(from.size());
    std::int64_t removed = 0;
    for (std::size_t s = 0; s < from.size(); ++s) {
        // A component of weight 0 is not seeded, as one the fit dropped.
        const bool remove = s % 7 == 3;
        removed += remove ? 1 : 0;
        reduced->components.column<GmmWeight>()[s] = remove ? 0.0 : from.column<GmmWeight>()[s];
        reduced->components.column<GmmPower>()[s] = from.column<GmmPower>()[s];
        reduced->components.column<GmmEffectiveCount>()[s] = from.column<GmmEffectiveCount>()[s];
        setGaussianAt(reduced->components, s, gaussianAt(from, s));
    }
    const Fit one = runFit(1, reduced);
    const Fit two = runFit(2, reduced);
    EXPECT_EQ(one.counters.at("restored_components"), removed);
    EXPECT_EQ(one.counters.at("components") + one.counters.at("dropped_components"), k);
    EXPECT_EQ(one.counters.at("components"), k);
    ASSERT_EQ(one.parameters.size(), two.parameters.size());
    EXPECT_EQ(std::memcmp(one.parameters.data(), two.parameters.data(), one.parameters.size() * sizeof(double)), 0);
    EXPECT_EQ(one.counters, two.counters);
    const Fit full = runFit(2, previous.mixture);
    EXPECT_EQ(full.counters.at("restored_components"), 0);
}

}  // namespace
}  // namespace fg
