// The guided-pt pipeline as the guiding tests build it: a short training
// block (importon, photon, index, cache_update) carrying the radiance cache,
// and the small training parameters they share.
#pragma once

#include "engine/core/job.h"
#include "engine/core/pass.h"

#include <cstdint>
#include <map>
#include <string>

namespace fg::test {

// Where cache_update makes new records: at the importons of the training pass
// (as the built-in guided-pt does) or at the photons (without an importons input).
enum class RecordsAt { Importons, Photons };

// The guided-pt pipeline with a short training block; `tail` is appended after it.
inline Pipeline guidedPipeline(int trainingPasses, const std::string& result, RecordsAt at = RecordsAt::Importons,
                        const std::string& tail = "[[pipeline.pass]]\npass = \"pt\"\ninputs = { radiance_cache = \"radiance_cache\" }\n") {
    const bool importons = at == RecordsAt::Importons;
    const std::string text = "[pipeline]\nname = \"guided-pt-test\"\nresults = [\"" + result +
                             "\"]\n[[pipeline.repeat]]\nname = \"train\"\ncount = " + std::to_string(trainingPasses) +
                             "\ncarry = { radiance_cache = \"radiance_cache\" }\n" +
                             (importons ? R"([[pipeline.repeat.pass]]
pass = "importon"
inputs = { radiance_cache = "radiance_cache" }
outputs = { importons = "training_importons" }
)"
                                        : "") +
                             R"([[pipeline.repeat.pass]]
pass = "photon"
outputs = { global_photons = "training_photons" }
[[pipeline.repeat.pass]]
pass = "photon_index"
name = "training_index"
inputs = { photons = "training_photons" }
outputs = { index = "training_index" }
[[pipeline.repeat.pass]]
pass = "cache_update"
name = "radiance_update"
inputs = { photons = "training_photons", index = "training_index", previous = "radiance_cache")" +
                             (importons ? ", importons = \"training_importons\"" : "") + " }\n" +
                             "outputs = { cache = \"radiance_cache\" }\n" + tail;
    return parsePipelineFile(text, "guided-pt-test.toml");
}

inline std::map<std::string, ParamValue> trainingParams(std::int64_t photons, std::int64_t spp) {
    return {{"photon.photons", photons},       {"photon.store", std::string("global")},
            {"photon.differentials", false},    {"pt.spp", spp},
            {"pt.max_depth", std::int64_t{12}},
            // Fewer training particles and a looser off-line EM than the paper's, to keep the tests short.
            {"radiance_update.training_particles", std::int64_t{64}},
            {"radiance_update.tolerance", 1e-3}};
}

}  // namespace fg::test
