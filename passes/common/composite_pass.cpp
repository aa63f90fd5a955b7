// Composite pass (`composite`): the image as the sum of the radiance layers
// that the estimators write, each on its own film from black. The layers are
// the terms of the radiance split of Jensen 1996 ("Global illumination using
// photon maps": direct light, caustics and the remaining indirect light, each
// estimated its own way; Frisvad et al. 2014 §4 compare splatting for the
// caustic term with gathering for the rest) and, in participating media, of
// Jakob et al. 2011 §3.1 Eq. 1, L = Tr L_s + L_m (the surface term from the eye
// pass and photon gathering, the media term from the beam query):
//
//   L = L_direct + L_caustic + L_global (+ L_volume).
//
// Because no estimator adds onto another's film, estimators of different terms
// run concurrently (e.g. the beam query alongside the surface gather), and
// each term can be looked at alone: `layer_channels` writes every layer's
// resolved RGB as AOVs `<layer>.R`, `<layer>.G`, `<layer>.B` of the image.
//
// Layers are resolved and summed per pixel in slot order (direct, caustic,
// global, volume), so the image does not depend on the thread count; it
// equals the film the estimators used to build by adding onto each other up
// to the order of floating-point sums. AOVs of the layers (e.g. the beam
// query's query_cost) are carried over to the image; an AOV two layers share
// is summed in slot order.
#include "passes/passes.h"

#include "engine/image/film.h"

#include <stdexcept>

namespace fg {

namespace {

// Layer slots in summation order.
const std::vector<std::string> kLayers = {"direct", "caustic", "global", "volume"};

void addInto(std::vector<float>& sum, const std::vector<float>& values) {
    for (std::size_t p = 0; p < sum.size(); ++p) sum[p] += values[p];
}

class CompositePass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const bool layerChannels = ctx.params().getBool("layer_channels");
        Film& image = ctx.createOutput<Film>("image", ctx.filmSettings());
        const std::size_t pixelCount = image.pixelCount();
        std::vector<Rgb> sum(pixelCount, Rgb(0.0f));
        std::int64_t layersSummed = 0;
        for (const std::string& slot : kLayers) {
            if (!ctx.hasInput(slot)) continue;
            const Film* layer = &ctx.input<Film>(slot);
            if (layer->width() != image.width() || layer->height() != image.height()) {
                throw std::logic_error("composite: layer '" + slot + "' is " + std::to_string(layer->width()) + "x" +
                                       std::to_string(layer->height()) + ", the image " +
                                       std::to_string(image.width()) + "x" + std::to_string(image.height()));
            }
            const std::vector<Rgb> radiance = layer->resolve();
            for (std::size_t p = 0; p < pixelCount; ++p) sum[p] += radiance[p];
            // image.aov() may move the channels when it creates one: no reference is held across calls.
            for (const auto& [name, values] : layer->aovs()) addInto(image.aov(name), values);
            if (layerChannels) {
                const char* const suffix[3] = {".R", ".G", ".B"};
                for (int c = 0; c < 3; ++c) {
                    std::vector<float>& channel = image.aov(slot + suffix[c]);
                    for (std::size_t p = 0; p < pixelCount; ++p) channel[p] = radiance[p][c];
                }
            }
            ++layersSummed;
        }
        // The image is black plus one direct addition of the sum: resolve() returns the sum exactly.
        image.addToPixels(sum, 1.0f);
        ctx.addItems(static_cast<std::int64_t>(pixelCount));
        ctx.addCounter("layers", layersSummed);
    }
};

std::vector<SlotSpec> layerSlots() {
    // Every layer is optional: a pipeline binds the terms it estimates.
    std::vector<SlotSpec> slots = {
        {"direct", "Film", "emission and direct light at the eye vertices (eye, volume_eye)"},
        {"caustic", "Film", "caustics, L S+ D (gather or splat)"},
        {"global", "Film", "indirect light other than caustics (gather, gather_global)"},
        {"volume", "Film", "media radiance L_m along camera segments (beam_query)"},
    };
    for (SlotSpec& slot : slots) slot.optional = true;
    return slots;
}

}  // namespace

PassRegistration compositePass() {
    PassSpec spec;
    spec.name = "composite";
    spec.doc = "The image as the sum of the radiance layers direct + caustic + global + volume, each written from "
               "black by its own estimator; layer AOVs carried over";
    spec.inputs = layerSlots();
    spec.outputs = {{"image", "Film", "sum of the layers, with their AOVs (and <layer>.R/G/B with layer_channels)"}};
    spec.params = {
        {"layer_channels", ParamType::Bool, false, 0, 0, {},
         "also write each layer's radiance as AOVs <layer>.R, <layer>.G, <layer>.B, to look at one term alone"},
    };
    const auto memory = [](const PreflightContext& pf) {
        return MemoryEstimate{filmBytes(pf.film),
                              "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height), {}};
    };
    return {spec, [] { return std::make_unique<CompositePass>(); }, {}, memory};
}

}  // namespace fg
