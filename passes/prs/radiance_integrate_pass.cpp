// Radiance integration (`radiance_integrate`): Herzog et al. 2007, §8.1. The
// radiance map holds, per glossy eye vertex, the spherical-harmonic
// coefficients of the splatted light times cos θ in the world frame
// (ray_splat with glossy = "sh_map"). Here they are rotated into the vertex
// frame (z = shading normal, x towards the outgoing direction) and dotted with
// the material's table F_lm(θ_o) = ∫ f_s(ω, ω_o) Y_lm(ω) dω:
//   L_o = Σ_lm c'_lm F_lm(θ_o)      (passes/prs/sh_radiance.h).
// The result, times the vertex's throughput, is added to the splatted film
// (Lambertian vertices went there directly). One table per material, built
// at the material's uv (0, 0): a glossy material whose specular reflectance
// is textured would need a table per texel and is integrated as if untextured.
// Lambertian vertices in the map (ray_splat lambertian = "sh_map", for the
// radiance cache of §8.3) need no table: as §8.1 says, one coefficient is
// enough, L_o = f_r ∫ E = f_r c_00 2√π, exact where the table's product with
// the truncated expansion is not, and with the vertex's own (textured) f_r.
// Tables are built in material order and vertices summed into pixels in map
// order, so the film does not depend on the thread count.
#include "passes/passes.h"
#include "passes/prs/sh_radiance.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <map>
#include <optional>
#include <span>
#include <tuple>
#include <utility>
#include <vector>

namespace fg {

namespace {

class RadianceIntegratePass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        const RadianceMap& map = ctx.input<RadianceMap>("radiance_map");
        const Film& splatted = ctx.input<Film>("splatted");
        Film& image = ctx.createOutput<Film>("radiance", ctx.filmSettings());
        const std::size_t pixelCount = image.pixelCount();
        std::vector<Rgb> total = splatted.resolve();
        if (total.size() != pixelCount) throw std::logic_error("radiance_integrate: the splatted film has another size");

        const auto vertexOf = map.vertices.column<MapVertex>();
        const auto columns = radianceMapShColumns(map.vertices);
        const auto bsdfOf = eye.column<EyeBsdf>();
        for (std::uint32_t v : vertexOf)
            if (v >= eye.size()) throw std::logic_error("radiance_integrate: map vertex outside the eye vertices");

        // One table per material the map refers to, in material order.
        std::vector<std::uint32_t> materials;
        for (std::uint32_t v : vertexOf)
            if (!scene.bsdfs[bsdfOf[v]]->constantReflectance(eye.column<EyeUv>()[v])) materials.push_back(bsdfOf[v]);
        std::sort(materials.begin(), materials.end());
        materials.erase(std::unique(materials.begin(), materials.end()), materials.end());
        std::vector<sh::BrdfTable> tables(materials.size());
        const int thetaSteps = static_cast<int>(ctx.params().getInt("table_steps"));
        jobs::parallelFor(materials.size(), 1, [&](std::size_t m) {
            tables[m] = sh::BrdfTable(*scene.bsdfs[materials[m]], Vec2(0.0f), thetaSteps);
        });
        const auto tableOf = [&](std::uint32_t bsdf) -> const sh::BrdfTable& {
            return tables[static_cast<std::size_t>(std::lower_bound(materials.begin(), materials.end(), bsdf) - materials.begin())];
        };

        const std::size_t count = map.vertices.size();
        std::vector<Rgb> radiance(count, Rgb(0.0f));
        jobs::parallelFor(count, 1024, [&](std::size_t g) {
            const std::uint32_t v = vertexOf[g];
            const EyeVertexBuffer::Record vertex = eye.get(v);
            const sh::VertexFrame frame = sh::vertexFrame(vertex.get<EyeNormal>(), vertex.get<EyeOutgoing>());
            if (!(frame.cosThetaO > 0.0f)) return;  // seen from below its shading normal
            sh::Coefficients<Rgb> world;
            for (std::size_t k = 0; k < sh::kCoefficients; ++k) world[k] = columns[k][g];
            const std::optional<Rgb> lambertian = scene.bsdfs[vertex.get<EyeBsdf>()]->constantReflectance(vertex.get<EyeUv>());
            if (lambertian) {
                const Rgb value = *lambertian * sh::integral(world) * vertex.get<EyeThroughput>();
                radiance[g] = isFinite(value) ? value : Rgb(0.0f);
                return;
            }
            const sh::Coefficients<Rgb> local = sh::Rotator::instance().rotate(world, frame.x, frame.y, frame.z);
            const Rgb value = tableOf(vertex.get<EyeBsdf>()).integrate(local, frame.cosThetaO) * vertex.get<EyeThroughput>();
            radiance[g] = isFinite(value) ? value : Rgb(0.0f);
        });
        const auto pixelOf = eye.column<EyePixel>();
        for (std::size_t g = 0; g < count; ++g) {
            const std::uint32_t pixel = pixelOf[vertexOf[g]];
            if (pixel >= pixelCount) throw std::logic_error("radiance_integrate: eye vertex outside the film");
            total[pixel] += radiance[g];
        }
        image.addToPixels(total, 1.0f);
        ctx.addItems(static_cast<std::int64_t>(count));
        ctx.addCounter("materials", static_cast<std::int64_t>(materials.size()));
    }
};

}  // namespace

PassRegistration radianceIntegratePass() {
    PassSpec spec;
    spec.name = "radiance_integrate";
    spec.doc = "Radiance from the SH radiance map at glossy eye vertices (Herzog et al. 2007, §8.1): rotate into the "
               "vertex frame, dot with the material's F_lm(theta_o) table; added to the splatted film";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "the vertices the map was splatted onto"},
        {"radiance_map", "RadianceMap", "per glossy vertex SH coefficients of the splatted light (ray_splat)"},
        {"splatted", "Film", "the splatted film (Lambertian vertices), which the glossy radiance is added to"},
    };
    spec.outputs = {{"radiance", "Film", "splatted film plus the integrated glossy radiance"}};
    spec.params = {
        {"table_steps", ParamType::Int, std::int64_t{32}, 2, 4096, {},
         "theta_o intervals of each material's F_lm table over [0, 90] degrees (linear interpolation)"},
    };
    return {spec, [] { return std::make_unique<RadianceIntegratePass>(); }};
}

}  // namespace fg
