// Photon tracing (`photon`): photon paths leave the lights, each light chosen
// in proportion to its power, and are traced through the scene's surfaces by
// BSDF sampling in importance transport (Jensen 1996, "Global Illumination
// using Photon Maps"), with Russian roulette on the path throughput. Every hit
// on a surface with a smooth (diffuse or glossy) lobe is a photon event,
// classified by the path so far:
//   direct   L D       first hit, stored only when asked (store_direct), in global_photons;
//   caustic  L S+ D    only specular events before: caustic_photons;
//   global   L ... D ... D   at least one non-specular event before: global_photons.
// Each photon carries its share of the source's flux: flux / (pmf(light) N).
//
// Photon differentials (Frisvad et al. 2014, §3; engine/differentials.h) are
// emitted with every path and followed across its leading chain of specular
// events (Igehy 1999); they end at the first non-specular event, so caustic
// and direct photons carry footprints (PhotonDu / PhotonDv) and global photons
// do not (zero vectors; global_photons.hasDifferentials stays false). N_e of
// Eqs. 5-6 is the expected number of paths from the chosen source, pmf(light) N.
// Photons whose footprint has collapsed are discarded and counted.
//
// Media are not simulated yet: rays travel straight through every medium, and
// surfaces without a BSDF or with a `null` one are crossed without an event.
//
// Determinism: path i draws from the stream (seed, "photon", i); a batch is
// split into fixed chunks, each chunk collects its photons in path order, and
// chunks are appended in order, so the maps do not depend on the thread count
// (nor on batch_size).
#include "passes/passes.h"

#include "engine/differentials.h"
#include "engine/photon_buffers.h"
#include "engine/ray_query.h"
#include "engine/scene.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>
#include <cstdint>
#include <vector>

namespace fg {

namespace {

constexpr std::size_t kGrain = 256;
// Null boundaries crossed by one segment; the bound only guards against degenerate geometry.
constexpr int kMaxNullCrossings = 1024;

struct Settings {
    std::uint64_t photons = 0;
    int maxDepth = 16;
    int rrDepth = 5;
    bool storeCaustic = true;
    bool storeGlobal = true;
    bool storeDirect = false;
    bool causticOnlyPaths = false;
    bool differentials = true;
    float smoothing = 10.0f;
    std::size_t batchSize = 1 << 18;
};

struct PhotonRecord {
    Vec3 position;
    Vec3 incident;
    Rgb power;
    Vec3 normal;
    std::uint8_t photonClass;
    Vec3 dxU;
    Vec3 dxV;
};

// What one chunk of paths produced, in path order.
struct ChunkResult {
    std::vector<PhotonRecord> caustic;
    std::vector<PhotonRecord> global;
    std::int64_t direct = 0;  // direct photons stored (they live in `global`)
    std::int64_t collapsedCaustic = 0;
    std::int64_t collapsedGlobal = 0;
    std::int64_t segments = 0;
};

class PhotonTracer {
public:
    PhotonTracer(const Scene& scene, const RayQuery& rays, const Settings& settings, std::uint64_t seed)
        : scene_(scene), rays_(rays), settings_(settings), seed_(seed) {}

    void trace(std::uint64_t pathIndex, ChunkResult& out) const {
        jobs::Rng rng(seed_, jobs::streamKey("photon"), pathIndex);
        const float uLight = rng.uniform();
        const Vec2 uPosition = rng.uniform2();
        const Vec2 uDirection = rng.uniform2();
        float pmf = 0.0f;
        const std::size_t lightIndex = scene_.lightPower.sampleDiscrete(uLight, &pmf);
        if (!(pmf > 0.0f)) return;
        const std::optional<EmissionSample> emission = scene_.lights[lightIndex]->sampleEmission(uPosition, uDirection);
        if (!emission) return;
        const double photonsFromSource = static_cast<double>(pmf) * static_cast<double>(settings_.photons);
        const Rgb power = emission->flux / static_cast<float>(photonsFromSource);
        if (isBlack(power) || !isFinite(power)) return;

        Vec3 direction = glm::normalize(emission->direction);
        bool tracking = settings_.differentials;
        PhotonDifferential differential;
        if (tracking) {
            differential = emitPhotonDifferential(direction, emission->normal, emission->emitterArea,
                                                  emission->emitterSolidAngle, photonsFromSource, settings_.smoothing);
        }
        Vec3 previous = emission->origin;
        Ray ray{offsetRayOrigin(emission->origin, emission->normal, direction), direction, kInfinity};
        Rgb throughput(1.0f);
        int depth = 0;
        bool specularChain = true;  // every event so far was specular
        int nullCrossings = 0;

        while (true) {
            const Hit hit = rays_.intersect(ray);
            ++out.segments;
            if (!hit.valid()) return;
            const SurfacePoint sp = rays_.surface(ray, hit);
            if (tracking) transferDifferential(differential, direction, glm::dot(sp.p - previous, direction), sp.ng);
            previous = sp.p;
            const Shape& shape = scene_.shapes[sp.shape];
            const Bsdf* bsdf = shape.bsdf >= 0 ? scene_.bsdfs[static_cast<std::size_t>(shape.bsdf)].get() : nullptr;
            if (!bsdf || bsdf->isNull()) {
                if (++nullCrossings > kMaxNullCrossings) return;
                ray = Ray{offsetRayOrigin(sp.p, sp.ng, direction), direction, kInfinity};
                continue;
            }
            nullCrossings = 0;
            ++depth;

            if (bsdf->hasSmoothLobe()) {
                const std::uint8_t photonClass =
                    depth == 1 ? PhotonClass::Direct : (specularChain ? PhotonClass::Caustic : PhotonClass::Global);
                store(photonClass, sp, direction, power * throughput, tracking ? &differential : nullptr, out);
                if (settings_.causticOnlyPaths) return;
            }
            if (depth >= settings_.maxDepth) return;

            const Frame frame(sp.ns);
            const Vec3 wo = frame.toLocal(-direction);
            const float uLobe = rng.uniform();
            const Vec2 uBsdf = rng.uniform2();
            const std::optional<BsdfSample> bs = bsdf->sample(wo, sp.uv, uLobe, uBsdf, TransportMode::Importance);
            if (!bs || bs->pdf <= 0.0f || isBlack(bs->weight)) return;
            const Vec3 wi = frame.toWorld(bs->wi);
            const float cosGeometricIn = glm::dot(wi, sp.ng);
            if (cosGeometricIn * bs->wi.z <= 0.0f) return;
            // Shading normals make importance transport non-symmetric (Veach 1997, §5.3.2):
            // the adjoint BSDF carries |wo.ns| |wi.ng| / (|wo.ng| |wi.ns|).
            const float adjointDenominator = std::abs(glm::dot(direction, sp.ng)) * std::abs(bs->wi.z);
            if (!(adjointDenominator > 0.0f)) return;
            throughput *= bs->weight * (std::abs(wo.z) * std::abs(cosGeometricIn) / adjointDenominator);

            if (bs->isSpecular()) {
                if (tracking) {
                    const Vec3 dnU = rays_.shadingNormalDifferential(ray, hit, differential.dxU);
                    const Vec3 dnV = rays_.shadingNormalDifferential(ray, hit, differential.dxV);
                    scatterDifferential(differential, direction, wi, sp.ns, dnU, dnV, *bs);
                }
            } else {
                specularChain = false;
                tracking = false;  // a differential means nothing after a non-specular event
            }
            direction = wi;
            ray = Ray{offsetRayOrigin(sp.p, sp.ng, wi), wi, kInfinity};

            if (depth >= settings_.rrDepth) {
                const float m = maxComponent(throughput);
                if (m < 1.0f) {
                    const float q = std::max(0.05f, 1.0f - m);
                    if (rng.uniform() < q) return;
                    throughput /= 1.0f - q;
                }
            }
        }
    }

private:
    void store(std::uint8_t photonClass, const SurfacePoint& sp, const Vec3& direction, const Rgb& power,
               const PhotonDifferential* differential, ChunkResult& out) const {
        const bool wanted = photonClass == PhotonClass::Direct    ? settings_.storeDirect
                            : photonClass == PhotonClass::Caustic ? settings_.storeCaustic
                                                                  : settings_.storeGlobal;
        if (!wanted || isBlack(power) || !isFinite(power)) return;
        const bool caustic = photonClass == PhotonClass::Caustic;
        PhotonRecord record{sp.p, -direction, power, sp.ns, photonClass, Vec3(0.0f), Vec3(0.0f)};
        if (differential) {
            if (footprintCollapsed(differential->dxU, differential->dxV, sp.ns)) {
                ++(caustic ? out.collapsedCaustic : out.collapsedGlobal);
                return;
            }
            record.dxU = differential->dxU;
            record.dxV = differential->dxV;
        }
        (caustic ? out.caustic : out.global).push_back(record);
        if (photonClass == PhotonClass::Direct) ++out.direct;
    }

    const Scene& scene_;
    const RayQuery& rays_;
    const Settings& settings_;
    std::uint64_t seed_;
};

void append(PhotonBuffer& buffer, const std::vector<PhotonRecord>& records) {
    if (records.empty()) return;
    const std::size_t first = buffer.size();
    buffer.resize(first + records.size());
    auto position = buffer.column<PhotonPosition>();
    auto incident = buffer.column<PhotonIncident>();
    auto power = buffer.column<PhotonPower>();
    auto normal = buffer.column<PhotonNormal>();
    auto photonClass = buffer.column<PhotonClassColumn>();
    auto du = buffer.column<PhotonDu>();
    auto dv = buffer.column<PhotonDv>();
    for (std::size_t k = 0; k < records.size(); ++k) {
        const PhotonRecord& r = records[k];
        const std::size_t i = first + k;
        position[i] = r.position;
        incident[i] = r.incident;
        power[i] = r.power;
        normal[i] = r.normal;
        photonClass[i] = r.photonClass;
        du[i] = r.dxU;
        dv[i] = r.dxV;
    }
}

class PhotonPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const PassParams& params = ctx.params();
        Settings settings;
        settings.photons = static_cast<std::uint64_t>(params.getInt("photons"));
        settings.maxDepth = static_cast<int>(params.getInt("max_depth"));
        settings.rrDepth = static_cast<int>(params.getInt("rr_depth"));
        const std::string& store = params.getString("store");
        settings.storeCaustic = store == "caustic" || store == "all";
        settings.storeGlobal = store == "global" || store == "all";
        settings.storeDirect = params.getBool("store_direct");
        settings.causticOnlyPaths = params.getBool("caustic_only_paths");
        settings.differentials = params.getBool("differentials");
        settings.smoothing = static_cast<float>(params.getFloat("smoothing"));
        settings.batchSize = static_cast<std::size_t>(params.getInt("batch_size"));

        PhotonMap& caustic = ctx.createOutput<PhotonMap>("caustic_photons");
        PhotonMap& global = ctx.createOutput<PhotonMap>("global_photons");
        caustic.emitted = global.emitted = settings.photons;
        caustic.hasDifferentials = settings.differentials;
        global.hasDifferentials = false;
        if (scene.lights.empty() || !(scene.lightPower.total() > 0.0f)) {
            ctx.addItems(static_cast<std::int64_t>(settings.photons));
            return;
        }

        const PhotonTracer tracer(scene, ctx.rays(), settings, ctx.seed());
        std::int64_t storedCaustic = 0, storedGlobal = 0, storedDirect = 0, segments = 0;
        for (std::uint64_t batchStart = 0; batchStart < settings.photons; batchStart += settings.batchSize) {
            const auto count = static_cast<std::size_t>(
                std::min<std::uint64_t>(settings.batchSize, settings.photons - batchStart));
            std::vector<ChunkResult> chunks((count + kGrain - 1) / kGrain);
            jobs::parallelForChunks(count, kGrain, [&](jobs::IndexRange r) {
                ChunkResult& out = chunks[r.begin / kGrain];
                for (std::size_t i = r.begin; i != r.end; ++i) tracer.trace(batchStart + i, out);
            });
            for (const ChunkResult& chunk : chunks) {
                append(caustic.photons, chunk.caustic);
                append(global.photons, chunk.global);
                caustic.collapsedFootprints += static_cast<std::uint64_t>(chunk.collapsedCaustic);
                global.collapsedFootprints += static_cast<std::uint64_t>(chunk.collapsedGlobal);
                storedCaustic += static_cast<std::int64_t>(chunk.caustic.size());
                storedDirect += chunk.direct;
                storedGlobal += static_cast<std::int64_t>(chunk.global.size()) - chunk.direct;
                segments += chunk.segments;
            }
            ctx.addItems(static_cast<std::int64_t>(count));
            ctx.reportProgress(static_cast<double>(batchStart + count) / static_cast<double>(settings.photons));
        }
        ctx.addCounter("caustic_photons", storedCaustic);
        ctx.addCounter("global_photons", storedGlobal);
        ctx.addCounter("direct_photons", storedDirect);
        ctx.addCounter("collapsed_footprints",
                       static_cast<std::int64_t>(caustic.collapsedFootprints + global.collapsedFootprints));
        ctx.addCounter("photon_segments", segments);
    }
};

}  // namespace

PassRegistration photonPass() {
    PassSpec spec;
    spec.name = "photon";
    spec.doc = "Photon tracing from all lights (by power) with Russian roulette and optional photon differentials";
    spec.outputs = {
        {"caustic_photons", "PhotonMap", "photons at smooth surfaces after only specular events (L S+ D), with footprints"},
        {"global_photons", "PhotonMap",
         "photons at smooth surfaces after a non-specular event (and direct photons with store_direct)"},
    };
    spec.params = {
        {"photons", ParamType::Int, std::int64_t{1000000}, 1, 1e15, {}, "photon paths emitted from all lights"},
        {"max_depth", ParamType::Int, std::int64_t{16}, 1, 4096, {},
         "maximum surface events per photon path; 1 = only the first hit (direct photons)"},
        {"rr_depth", ParamType::Int, std::int64_t{5}, 1, 4096, {},
         "surface events before Russian roulette may end a photon path"},
        {"store", ParamType::String, std::string("all"), 0, 0, {"caustic", "global", "all"},
         "which photon classes to keep: caustic (L S+ D), global (after a non-specular event), or all"},
        {"store_direct", ParamType::Bool, false, 0, 0, {},
         "also keep direct photons (L D) in global_photons; usually next-event estimation covers them"},
        {"caustic_only_paths", ParamType::Bool, false, 0, 0, {},
         "end every path at its first non-specular hit (enough for caustic photons)"},
        {"differentials", ParamType::Bool, true, 0, 0, {},
         "trace photon differentials and store footprints for caustic and direct photons"},
        {"smoothing", ParamType::Float, 10.0, 1e-3, 1e4, {},
         "smoothing s of the initial differentials: footprints of one source add up to s^2 times its area"},
        {"batch_size", ParamType::Int, std::int64_t{1 << 18}, 1, 1 << 26, {},
         "photon paths per batch (memory vs. parallelism); does not change the result"},
    };
    return {spec, [] { return std::make_unique<PhotonPass>(); }};
}

}  // namespace fg
