// Photon ray bandwidths (`ray_bandwidth`): Herzog et al. 2007, "Global
// Illumination using Photon Ray Splatting", §6 (Eq. 8 with the bounded path
// density of Eq. 7) and the sort of §3. A pilot over the first pilot_paths
// photon paths fixes the normalisation w and the scene scale mu_C; every ray
// then gets the conical frustum it splats with, h_0 and dh; the rays are
// finally put in the order of a 5D kd-tree over origin and direction (§3:
// "the created photon paths are sorted by means of a 5D kd-tree in spatial
// and directional domain"), so that rays splatted one after another touch
// the same eye vertices. How Eq. 8 is read: passes/prs/ray_bandwidth.h.
#include "passes/passes.h"
#include "passes/prs/ray_bandwidth.h"

#include "engine/buffers/photon_ray_buffers.h"
#include "engine/core/error.h"
#include "engine/scene/scene.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <vector>

namespace fg {

namespace {

// Rays per leaf of the ordering tree: below this, order no longer matters to the cache.
constexpr std::size_t kOrderLeafSize = 32;

// The five coordinates of a ray, each scaled to about [0, 1]: the origin in
// the rays' bounding box and the direction in octahedral coordinates.
std::array<float, 5> rayCoordinates(const Vec3& origin, const Vec3& direction, const Vec3& lo, const Vec3& extent) {
    std::array<float, 5> c{};
    for (int a = 0; a < 3; ++a) c[a] = extent[a] > 0.0f ? (origin[a] - lo[a]) / extent[a] : 0.0f;
    const float l1 = std::abs(direction.x) + std::abs(direction.y) + std::abs(direction.z);
    float u = direction.x / l1, v = direction.y / l1;
    if (direction.z < 0.0f) {
        const float fu = (1.0f - std::abs(v)) * (u >= 0.0f ? 1.0f : -1.0f);
        const float fv = (1.0f - std::abs(u)) * (v >= 0.0f ? 1.0f : -1.0f);
        u = fu;
        v = fv;
    }
    c[3] = 0.5f * (u + 1.0f);
    c[4] = 0.5f * (v + 1.0f);
    return c;
}

// Orders `order` as the leaves of a median-split kd-tree over the coordinates,
// splitting the dimension of largest extent; ties keep index order, so the
// result depends on the rays alone.
void kdOrder(std::vector<std::uint32_t>& order, const std::vector<std::array<float, 5>>& coords, std::size_t begin,
             std::size_t end) {
    while (end - begin > kOrderLeafSize) {
        std::array<float, 5> lo, hi;
        lo.fill(kInfinity);
        hi.fill(-kInfinity);
        for (std::size_t i = begin; i < end; ++i)
            for (int d = 0; d < 5; ++d) {
                lo[d] = std::min(lo[d], coords[order[i]][d]);
                hi[d] = std::max(hi[d], coords[order[i]][d]);
            }
        int axis = 0;
        for (int d = 1; d < 5; ++d)
            if (hi[d] - lo[d] > hi[axis] - lo[axis]) axis = d;
        if (!(hi[axis] > lo[axis])) return;
        const std::size_t middle = begin + (end - begin) / 2;
        std::nth_element(order.begin() + static_cast<std::ptrdiff_t>(begin),
                         order.begin() + static_cast<std::ptrdiff_t>(middle),
                         order.begin() + static_cast<std::ptrdiff_t>(end), [&](std::uint32_t a, std::uint32_t b) {
                             const float ca = coords[a][axis], cb = coords[b][axis];
                             return ca < cb || (ca == cb && a < b);
                         });
        kdOrder(order, coords, begin, middle);
        begin = middle;
    }
}

// out[i] = in[order[i]] for one column.
template <class Tag>
void gatherColumn(SplatRayBuffer& out, const PhotonRayBuffer& in, const std::vector<std::uint32_t>& order) {
    const auto from = in.column<Tag>();
    auto to = out.column<Tag>();
    for (std::size_t i = 0; i < order.size(); ++i) to[i] = from[order[i]];
}

class RayBandwidthPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const PhotonRays& input = ctx.input<PhotonRays>("photon_rays");
        const PassParams& params = ctx.params();
        BandwidthSettings settings;
        settings.smoothness = params.getFloat("smoothness");
        settings.sensitivity = params.getFloat("sensitivity");
        settings.maxScaling = params.getFloat("max_scaling");
        settings.pilotPaths = static_cast<std::uint64_t>(params.getInt("pilot_paths"));

        SplatRays& output = ctx.createOutput<SplatRays>("splat_rays");
        output.emitted = input.emitted;
        output.clampDistance = input.clampDistance;
        const PhotonRayBuffer& rays = input.rays;
        const std::size_t n = rays.size();
        const BandwidthModel model = fitBandwidthModel(rays, input.clampDistance, settings);
        output.countPerClass = model.countPerClass;
        output.normalisation = model.normalisation;
        output.sceneScale = model.sceneScale;
        if (n == 0) return;

        // The input stays with the scheduler until this pass ends, so only an
        // index permutation is sorted, its coordinates freed before the lean
        // output is gathered column by column: at most 24 bytes a ray beside
        // the input during the sort, 77 during the gather, never a second
        // full copy of the rays.
        std::vector<std::uint32_t> order(n);
        {
            const auto origin = rays.column<RayOrigin>();
            const auto direction = rays.column<RayDirection>();
            Vec3 lo(kInfinity), hi(-kInfinity);
            for (const Vec3& p : origin) {
                lo = glm::min(lo, p);
                hi = glm::max(hi, p);
            }
            std::vector<std::array<float, 5>> coords(n);
            for (std::size_t i = 0; i < n; ++i) coords[i] = rayCoordinates(origin[i], direction[i], lo, hi - lo);
            std::iota(order.begin(), order.end(), 0u);
            kdOrder(order, coords, 0, n);
        }

        SplatRayBuffer& out = output.rays;
        out.resize(n);
        gatherColumn<RayOrigin>(out, rays, order);
        gatherColumn<RayDirection>(out, rays, order);
        gatherColumn<RayLength>(out, rays, order);
        gatherColumn<RayPower>(out, rays, order);
        gatherColumn<RayClassColumn>(out, rays, order);
        gatherColumn<RayOriginNormal>(out, rays, order);
        gatherColumn<RayEndNormal>(out, rays, order);
        const auto originDensity = rays.column<RayOriginDensity>();
        const auto density = rays.column<RayDensity>();
        const auto vertex = rays.column<RayVertex>();
        const auto rayClass = out.column<RayClassColumn>();
        const auto length = out.column<RayLength>();
        auto h0 = out.column<RayH0>();
        auto dh = out.column<RayDh>();
        for (std::size_t i = 0; i < n; ++i) {
            const std::uint32_t from = order[i];
            const RayBandwidth b =
                rayBandwidth(model, originDensity[from], density[from], vertex[from], rayClass[i], length[i]);
            h0[i] = b.h0;
            dh[i] = b.dh;
        }

        ctx.addItems(static_cast<std::int64_t>(n));
        ctx.addCounter("direct_rays", static_cast<std::int64_t>(model.countPerClass[PhotonRayClass::Direct]));
        ctx.addCounter("caustic_rays", static_cast<std::int64_t>(model.countPerClass[PhotonRayClass::Caustic]));
        ctx.addCounter("global_rays", static_cast<std::int64_t>(model.countPerClass[PhotonRayClass::Global]));
        std::int64_t underflowed = 0;
        for (float p : rays.column<RayDensity>()) underflowed += readDensity(p) == 0.0;
        ctx.addCounter("underflowed_densities", underflowed);
    }
};

}  // namespace

PassRegistration rayBandwidthPass() {
    PassSpec spec;
    spec.name = "ray_bandwidth";
    spec.doc = "Photon ray splatting bandwidths (Herzog et al. 2007, §6, Eq. 8): pilot-normalised h_0 and dh per "
               "photon ray, rays sorted in 5D kd order";
    spec.inputs = {{"photon_rays", "PhotonRays", "photon rays with Eq. 7's bounded densities (photon pass, photon_rays = true)"}};
    spec.outputs = {{"splat_rays", "SplatRays",
                     "the same rays in 5D kd order, with h_0 and dh and only the columns the splat reads"}};
    spec.params = {
        {"smoothness", ParamType::Float, 1.0, 1e-6, 1e6, {}, "C of Eq. 8: scales every bandwidth"},
        {"sensitivity", ParamType::Float, 0.4, 1e-6, 1.0, {},
         "S of Eq. 8 in (0, 1]: how strongly h follows the path density (h ~ p~^(-S/2))"},
        {"max_scaling", ParamType::Float, 0.2, 1e-6, 1.0, {},
         "R: h is clamped to [R h̄, h̄ / R], h̄ = C mu_C (M / 1e5)^(-1/6) the typical bandwidth"},
        {"pilot_paths", ParamType::Int, std::int64_t{16384}, 1, 1e15, {},
         "the first this many photon paths estimate <r> and mu_C (§6's pilot shooting)"},
    };
    const auto preflight = [](const PreflightContext& pf) {
        const PassParams* photon = pf.producerParams("photon_rays");
        if (photon && pf.producerPass("photon_rays") == "photon" && !photon->getBool("photon_rays")) {
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': the photon pass records no photon rays; set photon_rays = true in its parameters");
        }
    };
    return {spec, [] { return std::make_unique<RayBandwidthPass>(); }, preflight, {}};
}

}  // namespace fg
