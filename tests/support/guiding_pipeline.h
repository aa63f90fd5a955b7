// The guided-pt pipeline as the guiding tests build it: a short training
// block (importon, photon, index, cache_update) carrying the radiance cache,
// or the built-in guided-pt block with the importance cache and guided
// photons, and the small training parameters they share.
#pragma once

#include "engine/core/job.h"
#include "engine/core/math.h"
#include "engine/core/pass.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <map>
#include <string>
#include <vector>

namespace fg::test {

// Where cache_update makes new records: at the importons of the training pass
// (as the built-in guided-pt does) or at the photons (without an importons input).
enum class RecordsAt { Importons, Photons };

inline constexpr const char* kGuidedPtPass = "[[pipeline.pass]]\npass = \"pt\"\ninputs = { radiance_cache = \"radiance_cache\" }\n";

namespace detail {

inline std::string pipelineHead(const std::string& name, const std::string& result, int trainingPasses,
                                const std::string& carry) {
    return "[pipeline]\nname = \"" + name + "\"\nresults = [\"" + result +
           "\"]\n[[pipeline.repeat]]\nname = \"train\"\ncount = " + std::to_string(trainingPasses) + "\ncarry = { " +
           carry + " }\n";
}

inline constexpr const char* kImportonPass = R"([[pipeline.repeat.pass]]
pass = "importon"
inputs = { radiance_cache = "radiance_cache" }
outputs = { importons = "training_importons" }
)";

inline constexpr const char* kIndexPass = R"([[pipeline.repeat.pass]]
pass = "photon_index"
name = "training_index"
inputs = { photons = "training_photons" }
outputs = { index = "training_index" }
)";

// The radiance update, with new records at the importons or at the photons.
inline std::string radianceUpdatePass(RecordsAt at) {
    return std::string(R"([[pipeline.repeat.pass]]
pass = "cache_update"
name = "radiance_update"
inputs = { photons = "training_photons", index = "training_index", previous = "radiance_cache")") +
           (at == RecordsAt::Importons ? ", importons = \"training_importons\"" : "") +
           " }\noutputs = { cache = \"radiance_cache\" }\n";
}

}  // namespace detail

// The guided-pt pipeline with a short training block (unguided photons, no
// importance cache); `tail` is appended after it.
inline Pipeline guidedPipeline(int trainingPasses, const std::string& result, RecordsAt at = RecordsAt::Importons,
                               const std::string& tail = kGuidedPtPass) {
    const std::string text = detail::pipelineHead("guided-pt-test", result, trainingPasses,
                                                  "radiance_cache = \"radiance_cache\"") +
                             (at == RecordsAt::Importons ? detail::kImportonPass : "") +
                             "[[pipeline.repeat.pass]]\npass = \"photon\"\noutputs = { global_photons = \"training_photons\" }\n" +
                             detail::kIndexPass + detail::radianceUpdatePass(at) + tail;
    return parsePipelineFile(text, "guided-pt-test.toml");
}

// The built-in guided-pt training block (passes/pipelines/guided-pt.toml):
// importons, the importance cache, photons guided by it, their index and the
// radiance cache, `trainingPasses` times; `tail` is appended after it (none:
// the result is one of the carried buffers).
inline Pipeline guidedTrainingPipeline(int trainingPasses, const std::string& result, const std::string& tail = "") {
    const std::string text =
        detail::pipelineHead("guided-training-test", result, trainingPasses,
                             "radiance_cache = \"radiance_cache\", importance_cache = \"importance_cache\", "
                             "training_photons = \"training_photons\"") +
        detail::kImportonPass + R"([[pipeline.repeat.pass]]
pass = "cache_update"
name = "importance_update"
inputs = { importance_training = "training_importons", photons = "training_photons", previous = "importance_cache" }
outputs = { cache = "importance_cache" }
[[pipeline.repeat.pass]]
pass = "photon"
inputs = { importance_cache = "importance_cache" }
outputs = { global_photons = "training_photons" }
)" + detail::kIndexPass +
        detail::radianceUpdatePass(RecordsAt::Importons) + tail;
    return parsePipelineFile(text, "guided-training-test.toml");
}

inline std::map<std::string, ParamValue> trainingParams(std::int64_t photons, std::int64_t spp) {
    return {{"photon.photons", photons},       {"photon.store", std::string("global")},
            {"photon.differentials", false},    {"pt.spp", spp},
            {"pt.max_depth", std::int64_t{12}},
            // Fewer training particles and a looser off-line EM than the paper's, to keep the tests short.
            {"radiance_update.training_particles", std::int64_t{64}},
            {"radiance_update.tolerance", 1e-3}};
}

// Training of both caches (importance from importons, radiance from photons)
// for the built-in guided bdpt and guided-photon pipelines.
inline std::map<std::string, ParamValue> bothCachesTrainingParams(std::int64_t photons) {
    return {{"importon.spp", std::int64_t{4}},
            {"photon.photons", photons},
            {"photon.store", std::string("global")},
            {"photon.differentials", false},
            // Fewer training particles than the paper's 250, to keep the tests short.
            {"radiance_update.training_particles", std::int64_t{64}},
            {"importance_update.training_particles", std::int64_t{64}}};
}

// A guided image must not be black and must be the same bytes at 1 and 2 threads.
inline void expectSameNonBlackImage(const std::vector<Rgb>& one, const std::vector<Rgb>& two) {
    ASSERT_EQ(one.size(), two.size());
    double sum = 0.0;
    for (const Rgb& p : one) sum += p.x + p.y + p.z;
    EXPECT_GT(sum, 0.0);
    EXPECT_EQ(std::memcmp(one.data(), two.data(), one.size() * sizeof(Rgb)), 0);
}

}  // namespace fg::test
