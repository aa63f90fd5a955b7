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
const std::vector<std::string> kSurfaceLayers = {"direct", "caustic", "global"};
const std::vector<std::string> kAllLayers = {"direct", "caustic", "global", "volume"};

// The layer bound to `slot`, or null when the slot holds no film. PassContext
// offers no presence query, and input() reports an unbound slot and a handle
// without data as logic errors: both mean "this layer is absent" here (types
// are checked by the scheduler before any pass runs).
const Film* layerIfPresent(const PassContext& ctx, const std::string& slot) {
    try {
        return &ctx.input<Film>(slot);
    } catch (const std::logic_error&) {
        return nullptr;
    }
}

void addInto(std::vector<float>& sum, const std::vector<float>& values) {
    for (std::size_t p = 0; p < sum.size(); ++p) sum[p] += values[p];
}

class CompositePass final : public Pass {
public:
    explicit CompositePass(const std::vector<std::string>& layers) : layers_(layers) {}

    void run(PassContext& ctx) override {
        const bool layerChannels = ctx.params().getBool("layer_channels");
        Film& image = ctx.createOutput<Film>("image", ctx.filmSettings());
        const std::size_t pixelCount = image.pixelCount();
        std::vector<Rgb> sum(pixelCount, Rgb(0.0f));
        std::int64_t layersSummed = 0;
        for (const std::string& slot : layers_) {
            const Film* layer = layerIfPresent(ctx, slot);
            if (!layer) continue;
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

private:
    std::vector<std::string> layers_;
};

std::vector<SlotSpec> layerSlots(const std::vector<std::string>& layers) {
    std::vector<SlotSpec> slots;
    for (const std::string& layer : layers) {
        if (layer == "direct")
            slots.push_back({"direct", "Film", "emission and direct light at the eye vertices (eye, volume_eye)"});
        else if (layer == "caustic")
            slots.push_back({"caustic", "Film", "caustics, L S+ D (gather or splat)"});
        else if (layer == "global")
            slots.push_back({"global", "Film", "indirect light other than caustics (gather, gather_global)"});
        else if (layer == "volume")
            // optional: only pipelines with media have it; until slots can be
            // declared optional, surface-only pipelines use composite_surface.
            slots.push_back({"volume", "Film", "media radiance L_m along camera segments (beam_query)"});
    }
    return slots;
}

PassSpec compositeSpec(std::string name, const std::vector<std::string>& layers, std::string doc) {
    PassSpec spec;
    spec.name = std::move(name);
    spec.doc = std::move(doc);
    spec.inputs = layerSlots(layers);
    spec.outputs = {{"image", "Film", "sum of the layers, with their AOVs (and <layer>.R/G/B with layer_channels)"}};
    spec.params = {
        {"layer_channels", ParamType::Bool, false, 0, 0, {},
         "also write each layer's radiance as AOVs <layer>.R, <layer>.G, <layer>.B, to look at one term alone"},
    };
    return spec;
}

}  // namespace

PassRegistration compositePass() {
    return {compositeSpec("composite", kAllLayers,
                          "The image as the sum of the radiance layers direct + caustic + global + volume, each "
                          "written from black by its own estimator; layer AOVs carried over"),
            [] { return std::make_unique<CompositePass>(kAllLayers); }};
}

// The same pass without the volume layer, for pipelines without media: the
// scheduler needs every declared input produced, and cannot yet be told that
// `volume` is optional.
PassRegistration compositeSurfacePass() {
    return {compositeSpec("composite_surface", kSurfaceLayers,
                          "The image as the sum of the surface radiance layers direct + caustic + global, each "
                          "written from black by its own estimator (composite without the volume layer)"),
            [] { return std::make_unique<CompositePass>(kSurfaceLayers); }};
}

}  // namespace fg
