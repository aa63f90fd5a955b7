// Ray/scene queries on top of Embree 3 (Wald et al. 2014, "Embree: A Kernel
// Framework for Efficient CPU Ray Tracing"). Triangle meshes are copied into
// Embree-owned buffers (Embree wants 16 bytes readable past the last vertex,
// which a std::vector<Vec3> does not promise). Spheres are user geometry with
// an analytic intersector: the quadratic is solved in double precision with
// the discriminant written as r^2 - |perpendicular offset|^2 and the two roots
// taken as c/q and q/a, which avoids both catastrophic cancellations
// (Haines, Guenter, Akenine-Moller, "Precision Improvements for Ray/Sphere
// Intersection", Ray Tracing Gems, 2019, ch. 7).
// Geometry ids are attached explicitly so that geometry id == shape index.
// A mesh shared by several shapes (MeshInstance) gets one Embree scene of its
// own, and each of those shapes an Embree instance of it with its transform;
// a hit reports the instance's id, and surface() moves the hit triangle into
// world space.
#include "engine/accel/ray_query.h"

#include <embree3/rtcore.h>
#include <glm/gtc/type_ptr.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <tuple>
#include <vector>

namespace fg {

namespace {

struct SphereGeometry {
    glm::dvec3 center{0.0};
    double radius = 1.0;
    bool flipNormals = false;
    // The same, in float (as the scene stores them), for certainlyMissesSphere.
    Vec3 floatCenter{0.0f};
    float floatRadius = 1.0f;
};

// Both ray parameters where the line o + t d crosses the sphere, t0 <= t1.
bool solveSphere(const SphereGeometry& sphere, const glm::dvec3& o, const glm::dvec3& d, double* t0, double* t1) {
    const double a = glm::dot(d, d);
    if (!(a > 0.0)) return false;
    const glm::dvec3 f = o - sphere.center;
    const double halfB = -glm::dot(f, d);
    // Offset of the centre from the line: its squared length is exact enough even
    // when |f| is far larger than the radius, unlike b^2 - 4ac.
    const glm::dvec3 perpendicular = f + (halfB / a) * d;
    const double r2 = sphere.radius * sphere.radius;
    const double discriminant = a * (r2 - glm::dot(perpendicular, perpendicular));
    if (discriminant < 0.0) return false;
    const double c = glm::dot(f, f) - r2;
    const double q = halfB + std::copysign(std::sqrt(discriminant), halfB);
    if (q == 0.0) {
        *t0 = *t1 = 0.0;  // the origin lies on the sphere and the ray is tangent
        return true;
    }
    *t0 = c / q;
    *t1 = q / a;
    if (*t0 > *t1) std::swap(*t0, *t1);
    return true;
}

// The first crossing inside [tNear, tFar]; a ray starting inside gets the exit point.
bool nearestSphereHit(const SphereGeometry& sphere, const glm::dvec3& o, const glm::dvec3& d, float tNear, float tFar,
                      double* t) {
    double t0, t1;
    if (!solveSphere(sphere, o, d, &t0, &t1)) return false;
    if (t0 >= tNear && t0 <= tFar) {
        *t = t0;
        return true;
    }
    if (t1 >= tNear && t1 <= tFar) {
        *t = t1;
        return true;
    }
    return false;
}

// True when the line o + t d certainly passes the sphere by: its distance from
// the centre, computed in float, exceeds the radius by more than float
// rounding could account for. A scene with one sphere has a one-primitive
// user-geometry hierarchy, whose leaf Embree enters without a box test, so
// every ray of the scene comes here; most miss, and this test settles them
// without the double-precision solve. Hits (and the rare near misses) still
// go through solveSphere unchanged, so the reported t is the same as without
// the test.
bool certainlyMissesSphere(const SphereGeometry& sphere, const Vec3& o, const Vec3& d) {
    const float a = glm::dot(d, d);
    if (!(a > 0.0f)) return false;
    const Vec3 f = o - sphere.floatCenter;
    const Vec3 perpendicular = f - (glm::dot(f, d) / a) * d;
    // The rounding error of the offset is a few float epsilons (6e-8) of |f| and
    // |center|; 1e-5 of them leaves a margin of two orders of magnitude. NaNs
    // compare false and go to the exact solve.
    const float reach = sphere.floatRadius * (1.0f + 1e-5f) + 1e-5f * (glm::length(f) + glm::length(sphere.floatCenter));
    return glm::dot(perpendicular, perpendicular) > reach * reach;
}

Vec3 orientedSphereNormal(const SphereGeometry& sphere, const Vec3& p) {
    const Vec3 outward = glm::normalize(p - Vec3(sphere.center));
    return sphere.flipNormals ? -outward : outward;
}

void sphereBounds(const RTCBoundsFunctionArguments* args) {
    const auto* sphere = static_cast<const SphereGeometry*>(args->geometryUserPtr);
    // Slightly enlarged so float rounding of the box never clips the sphere.
    const double r = sphere->radius * (1.0 + 1e-6) + 1e-7 * glm::length(sphere->center);
    RTCBounds* b = args->bounds_o;
    b->lower_x = static_cast<float>(sphere->center.x - r);
    b->lower_y = static_cast<float>(sphere->center.y - r);
    b->lower_z = static_cast<float>(sphere->center.z - r);
    b->upper_x = static_cast<float>(sphere->center.x + r);
    b->upper_y = static_cast<float>(sphere->center.y + r);
    b->upper_z = static_cast<float>(sphere->center.z + r);
}

void sphereIntersect(const RTCIntersectFunctionNArguments* args) {
    const auto* sphere = static_cast<const SphereGeometry*>(args->geometryUserPtr);
    const unsigned n = args->N;
    RTCRayN* rays = RTCRayHitN_RayN(args->rayhit, n);
    RTCHitN* hits = RTCRayHitN_HitN(args->rayhit, n);
    for (unsigned i = 0; i < n; ++i) {
        if (args->valid[i] != -1) continue;
        const Vec3 floatOrigin(RTCRayN_org_x(rays, n, i), RTCRayN_org_y(rays, n, i), RTCRayN_org_z(rays, n, i));
        const Vec3 floatDirection(RTCRayN_dir_x(rays, n, i), RTCRayN_dir_y(rays, n, i), RTCRayN_dir_z(rays, n, i));
        if (certainlyMissesSphere(*sphere, floatOrigin, floatDirection)) continue;
        const glm::dvec3 o(floatOrigin), d(floatDirection);
        double t;
        if (!nearestSphereHit(*sphere, o, d, RTCRayN_tnear(rays, n, i), RTCRayN_tfar(rays, n, i), &t)) continue;
        const Vec3 ng = orientedSphereNormal(*sphere, Vec3(o + t * d));
        RTCRayN_tfar(rays, n, i) = static_cast<float>(t);
        RTCHitN_Ng_x(hits, n, i) = ng.x;
        RTCHitN_Ng_y(hits, n, i) = ng.y;
        RTCHitN_Ng_z(hits, n, i) = ng.z;
        RTCHitN_u(hits, n, i) = 0.0f;
        RTCHitN_v(hits, n, i) = 0.0f;
        RTCHitN_primID(hits, n, i) = args->primID;
        RTCHitN_geomID(hits, n, i) = args->geomID;
        for (unsigned level = 0; level < RTC_MAX_INSTANCE_LEVEL_COUNT; ++level) {
            RTCHitN_instID(hits, n, i, level) = args->context->instID[level];
        }
    }
}

void sphereOccluded(const RTCOccludedFunctionNArguments* args) {
    const auto* sphere = static_cast<const SphereGeometry*>(args->geometryUserPtr);
    const unsigned n = args->N;
    RTCRayN* rays = args->ray;
    for (unsigned i = 0; i < n; ++i) {
        if (args->valid[i] != -1) continue;
        const Vec3 floatOrigin(RTCRayN_org_x(rays, n, i), RTCRayN_org_y(rays, n, i), RTCRayN_org_z(rays, n, i));
        const Vec3 floatDirection(RTCRayN_dir_x(rays, n, i), RTCRayN_dir_y(rays, n, i), RTCRayN_dir_z(rays, n, i));
        if (certainlyMissesSphere(*sphere, floatOrigin, floatDirection)) continue;
        const glm::dvec3 o(floatOrigin), d(floatDirection);
        double t;
        if (nearestSphereHit(*sphere, o, d, RTCRayN_tnear(rays, n, i), RTCRayN_tfar(rays, n, i), &t)) {
            RTCRayN_tfar(rays, n, i) = -std::numeric_limits<float>::infinity();
        }
    }
}

RTCRay toEmbreeRay(const Ray& ray, float tMin) {
    RTCRay r;
    r.org_x = ray.origin.x;
    r.org_y = ray.origin.y;
    r.org_z = ray.origin.z;
    r.tnear = tMin;
    r.dir_x = ray.direction.x;
    r.dir_y = ray.direction.y;
    r.dir_z = ray.direction.z;
    r.time = 0.0f;
    r.tfar = ray.tMax;
    r.mask = 0xFFFFFFFFu;
    r.id = 0;
    r.flags = 0;
    return r;
}

RTCRayHit toEmbreeRayHit(const Ray& ray, float tMin) {
    RTCRayHit rh;
    rh.ray = toEmbreeRay(ray, tMin);
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
    for (unsigned level = 0; level < RTC_MAX_INSTANCE_LEVEL_COUNT; ++level) rh.hit.instID[level] = RTC_INVALID_GEOMETRY_ID;
    return rh;
}

Hit fromEmbreeRayHit(const RTCRayHit& rh) {
    Hit hit;
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return hit;
    hit.t = rh.ray.tfar;
    // Shapes that instance a shared mesh are hit through their instance.
    hit.shape = rh.hit.instID[0] != RTC_INVALID_GEOMETRY_ID ? rh.hit.instID[0] : rh.hit.geomID;
    hit.primitive = rh.hit.primID;
    hit.barycentric = Vec2(rh.hit.u, rh.hit.v);
    hit.geometricNormal = Vec3(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
    return hit;
}

// Every query, single or streamed, is marked incoherent. Embree's coherent
// mode (packet traversal of camera-like streams) visits leaves in another
// order than its single-ray kernel, so where two triangles are hit at the
// same t (coplanar overlaps such as the Cornell box ceiling's light opening,
// or faces duplicated across shapes in the conference scene) it reports the
// other one, and its t can differ in the last bit: the wavefront and tile
// schedules of `pt` then rendered different images. Incoherent streams leave
// each ray to the single-ray kernel once its packet has spread out, and gave
// the same hits as rtcIntersect1 on every data `pt` job and on the scene of
// tools/bench_vs_embree.sh (RayQuery.CameraStreamHitsWhatSingleRaysHit keeps
// watch). There, at one thread, the incoherent camera streams cost about 2 %
// of `pt`'s CPU time and rtcIntersect1 ray by ray about 20 %.
RTCIntersectContext makeIncoherentContext() {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    context.flags = RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
    return context;
}

// The corners of a hit triangle in world space. An instance's are transformed
// as TriangleMesh::transform would transform a copy (normals by the inverse
// transpose); a mirroring placement reverses the winding, which `orientation`
// undoes instead of swapping corners, so that Embree's barycentrics still
// refer to corners 1 and 2.
struct TriangleCorners {
    Vec3 p[3];
    Vec3 n[3];
    Vec2 uv[3];
    bool hasNormals = false, hasUvs = false;
    float orientation = 1.0f;
};

TriangleCorners cornersOf(const Shape& shape, std::uint32_t primitive) {
    const auto* instance = std::get_if<MeshInstance>(&shape.geometry);
    const TriangleMesh& mesh = instance ? *instance->mesh : std::get<TriangleMesh>(shape.geometry);
    const std::size_t base = 3 * static_cast<std::size_t>(primitive);
    TriangleCorners c;
    c.hasNormals = !mesh.normals.empty();
    c.hasUvs = !mesh.uvs.empty();
    for (int k = 0; k < 3; ++k) {
        const std::uint32_t i = mesh.indices[base + static_cast<std::size_t>(k)];
        c.p[k] = mesh.positions[i];
        if (c.hasNormals) c.n[k] = mesh.normals[i];
        if (c.hasUvs) c.uv[k] = mesh.uvs[i];
    }
    if (instance) {
        const Mat3 linear(instance->toWorld);
        const Mat3 normalMatrix = glm::transpose(glm::inverse(linear));
        for (int k = 0; k < 3; ++k) {
            c.p[k] = instance->point(c.p[k]);
            if (c.hasNormals) c.n[k] = glm::normalize(normalMatrix * c.n[k]);
        }
        if (glm::determinant(linear) < 0.0f) c.orientation = -1.0f;
    }
    return c;
}

// Rays go to Embree in chunks that fit comfortably on the stack.
constexpr std::size_t kStreamChunk = 256;

// Embree's default (fast) traversal and triangle test rather than
// RTC_SCENE_FLAG_ROBUST: on the Cornell box of tools/bench_vs_embree.sh the
// robust mode costs 12-14 ms of the path tracer's 81-85 ms of CPU time per
// sample at one thread (README, `pt` against Embree). What it buys is
// watertightness at shared edges: rays from inside a closed, rotated,
// tessellated cube escape through it 4 times in 3e7 when aimed at uniformly
// random points of its surface (robust: never), so a path is lost about once
// in 10^7 segments, far below any image's noise
// (RayQuery.ClosedMeshKeepsRandomRaysIn). Rays aimed exactly at an edge or a
// vertex leak far more often (4 % and 15 %), which no sampled direction does.
constexpr RTCSceneFlags kSceneFlags = RTC_SCENE_FLAG_NONE;

}  // namespace

struct RayQuery::Impl {
    RTCDevice device = nullptr;
    RTCScene scene = nullptr;
    std::vector<SphereGeometry> spheres;  // user data of the sphere geometries; never resized after build
    std::unordered_map<const TriangleMesh*, RTCScene> sharedMeshes;  // one Embree scene per shared mesh
    std::mutex errorMutex;
    std::string firstError;

    ~Impl() {
        if (scene) rtcReleaseScene(scene);
        for (const auto& [mesh, shared] : sharedMeshes) rtcReleaseScene(shared);
        if (device) rtcReleaseDevice(device);
    }

    void recordError(RTCError code, const char* message) {
        std::lock_guard lock(errorMutex);
        if (firstError.empty()) firstError = "Embree error " + std::to_string(static_cast<int>(code)) + ": " + (message ? message : "");
    }

    void throwIfFailed(const char* what) {
        const RTCError code = rtcGetDeviceError(device);
        std::lock_guard lock(errorMutex);
        if (code != RTC_ERROR_NONE || !firstError.empty()) {
            throw std::runtime_error(std::string(what) + ": " +
                                     (firstError.empty() ? "Embree error " + std::to_string(static_cast<int>(code)) : firstError));
        }
    }

    void addMesh(unsigned id, const TriangleMesh& mesh, RTCScene target = nullptr) {
        if (mesh.triangleCount() == 0 || mesh.positions.empty()) return;
        RTCGeometry geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
        auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                                     3 * sizeof(float), mesh.positions.size()));
        auto* indices = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                       3 * sizeof(unsigned), mesh.triangleCount()));
        if (!vertices || !indices) {
            rtcReleaseGeometry(geometry);
            throwIfFailed("cannot allocate triangle buffers");
            throw std::runtime_error("cannot allocate triangle buffers");
        }
        for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
            vertices[3 * v + 0] = mesh.positions[v].x;
            vertices[3 * v + 1] = mesh.positions[v].y;
            vertices[3 * v + 2] = mesh.positions[v].z;
        }
        for (std::size_t i = 0; i < 3 * mesh.triangleCount(); ++i) indices[i] = mesh.indices[i];
        rtcCommitGeometry(geometry);
        rtcAttachGeometryByID(target ? target : scene, geometry, id);
        rtcReleaseGeometry(geometry);
    }

    void addInstance(unsigned id, const MeshInstance& instance) {
        const TriangleMesh& mesh = *instance.mesh;
        if (mesh.triangleCount() == 0 || mesh.positions.empty()) return;
        RTCScene& shared = sharedMeshes[&mesh];
        if (!shared) {
            shared = rtcNewScene(device);
            rtcSetSceneFlags(shared, kSceneFlags);
            rtcSetSceneBuildQuality(shared, RTC_BUILD_QUALITY_HIGH);
            addMesh(0, mesh, shared);
            rtcCommitScene(shared);
        }
        RTCGeometry geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(geometry, shared);
        rtcSetGeometryTimeStepCount(geometry, 1);
        rtcSetGeometryTransform(geometry, 0, RTC_FORMAT_FLOAT4X4_COLUMN_MAJOR, glm::value_ptr(instance.toWorld));
        rtcCommitGeometry(geometry);
        rtcAttachGeometryByID(scene, geometry, id);
        rtcReleaseGeometry(geometry);
    }

    void addSphere(unsigned id, SphereGeometry* sphere) {
        RTCGeometry geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
        rtcSetGeometryUserPrimitiveCount(geometry, 1);
        rtcSetGeometryUserData(geometry, sphere);
        rtcSetGeometryBoundsFunction(geometry, sphereBounds, nullptr);
        rtcSetGeometryIntersectFunction(geometry, sphereIntersect);
        rtcSetGeometryOccludedFunction(geometry, sphereOccluded);
        rtcCommitGeometry(geometry);
        rtcAttachGeometryByID(scene, geometry, id);
        rtcReleaseGeometry(geometry);
    }
};

RayQuery::RayQuery(const Scene& scene) : scene_(scene), impl_(std::make_unique<Impl>()) {
    Impl& impl = *impl_;
    impl.device = rtcNewDevice(nullptr);
    if (!impl.device) throw std::runtime_error("cannot create the Embree device");
    rtcSetDeviceErrorFunction(
        impl.device,
        [](void* user, RTCError code, const char* message) { static_cast<Impl*>(user)->recordError(code, message); },
        &impl);
    impl.scene = rtcNewScene(impl.device);
    rtcSetSceneFlags(impl.scene, kSceneFlags);
    rtcSetSceneBuildQuality(impl.scene, RTC_BUILD_QUALITY_HIGH);

    std::size_t sphereCount = 0;
    for (const Shape& shape : scene.shapes) sphereCount += shape.isSphere() ? 1 : 0;
    impl.spheres.reserve(sphereCount);
    for (std::size_t i = 0; i < scene.shapes.size(); ++i) {
        const Shape& shape = scene.shapes[i];
        const auto id = static_cast<unsigned>(i);
        if (const auto* sphere = std::get_if<Sphere>(&shape.geometry)) {
            impl.spheres.push_back({glm::dvec3(sphere->center), static_cast<double>(sphere->radius), shape.flipNormals,
                                    sphere->center, sphere->radius});
            impl.addSphere(id, &impl.spheres.back());
        } else if (const auto* instance = std::get_if<MeshInstance>(&shape.geometry)) {
            impl.addInstance(id, *instance);
        } else {
            impl.addMesh(id, std::get<TriangleMesh>(shape.geometry));
        }
    }
    rtcCommitScene(impl.scene);
    impl.throwIfFailed("cannot build the ray-tracing acceleration structure");
}

RayQuery::~RayQuery() = default;

Hit RayQuery::intersect(const Ray& ray, float tMin) const {
    RTCIntersectContext context = makeIncoherentContext();
    RTCRayHit rh = toEmbreeRayHit(ray, tMin);
    rtcIntersect1(impl_->scene, &context, &rh);
    return fromEmbreeRayHit(rh);
}

bool RayQuery::occluded(const Ray& ray, float tMin) const {
    RTCIntersectContext context = makeIncoherentContext();
    RTCRay r = toEmbreeRay(ray, tMin);
    rtcOccluded1(impl_->scene, &context, &r);
    return r.tfar < 0.0f;
}

void RayQuery::intersect(std::span<const Ray> rays, std::span<Hit> out, float tMin) const {
    if (out.size() < rays.size()) throw std::invalid_argument("RayQuery::intersect: output span shorter than input");
    RTCIntersectContext context = makeIncoherentContext();
    RTCRayHit buffer[kStreamChunk];
    for (std::size_t begin = 0; begin < rays.size(); begin += kStreamChunk) {
        const std::size_t count = std::min(kStreamChunk, rays.size() - begin);
        for (std::size_t i = 0; i < count; ++i) {
            buffer[i] = toEmbreeRayHit(rays[begin + i], tMin);
            buffer[i].ray.id = static_cast<unsigned>(i);
        }
        rtcIntersect1M(impl_->scene, &context, buffer, static_cast<unsigned>(count), sizeof(RTCRayHit));
        for (std::size_t i = 0; i < count; ++i) out[begin + i] = fromEmbreeRayHit(buffer[i]);
    }
}

void RayQuery::occluded(std::span<const Ray> rays, std::span<std::uint8_t> occludedOut, float tMin) const {
    if (occludedOut.size() < rays.size()) throw std::invalid_argument("RayQuery::occluded: output span shorter than input");
    RTCIntersectContext context = makeIncoherentContext();
    RTCRay buffer[kStreamChunk];
    for (std::size_t begin = 0; begin < rays.size(); begin += kStreamChunk) {
        const std::size_t count = std::min(kStreamChunk, rays.size() - begin);
        for (std::size_t i = 0; i < count; ++i) {
            buffer[i] = toEmbreeRay(rays[begin + i], tMin);
            buffer[i].id = static_cast<unsigned>(i);
        }
        rtcOccluded1M(impl_->scene, &context, buffer, static_cast<unsigned>(count), sizeof(RTCRay));
        for (std::size_t i = 0; i < count; ++i) occludedOut[begin + i] = buffer[i].tfar < 0.0f ? 1 : 0;
    }
}

namespace {

// interpolatedSurface for a mesh in world space, the case of nearly every hit:
// the same arithmetic as the general path through cornersOf, without copying
// all three corners' attributes or the instance and orientation checks.
void meshSurface(const TriangleMesh& mesh, const Hit& hit, SurfacePoint& sp) {
    sp.mesh = &mesh;
    sp.triangle = hit.primitive;
    sp.barycentric = hit.barycentric;
    const std::uint32_t* corner = mesh.indices.data() + 3 * static_cast<std::size_t>(hit.primitive);
    const std::uint32_t i0 = corner[0], i1 = corner[1], i2 = corner[2];
    const float b1 = hit.barycentric.x, b2 = hit.barycentric.y, b0 = 1.0f - b1 - b2;
    const Vec3& p0 = mesh.positions[i0];
    const Vec3& p1 = mesh.positions[i1];
    const Vec3& p2 = mesh.positions[i2];
    sp.p = b0 * p0 + b1 * p1 + b2 * p2;
    const Vec3 cross = glm::cross(p1 - p0, p2 - p0);
    const float crossLength = glm::length(cross);
    sp.ng = crossLength > 0.0f ? cross / crossLength : Vec3(0.0f, 0.0f, 1.0f);
    sp.ns = sp.ng;
    if (!mesh.normals.empty()) {
        const Vec3 interpolated = b0 * mesh.normals[i0] + b1 * mesh.normals[i1] + b2 * mesh.normals[i2];
        const float nLength = glm::length(interpolated);
        if (nLength > 0.0f && std::isfinite(nLength)) {
            sp.ns = interpolated / nLength;
            if (glm::dot(sp.ns, sp.ng) < 0.0f) sp.ns = -sp.ns;
        }
    }
    sp.uv = !mesh.uvs.empty() ? b0 * mesh.uvs[i0] + b1 * mesh.uvs[i1] + b2 * mesh.uvs[i2] : Vec2(b1, b2);
}

SurfacePoint interpolatedSurface(const Scene& scene, const Ray& ray, const Hit& hit) {
    SurfacePoint sp;
    if (!hit.valid()) return sp;
    sp.shape = hit.shape;
    const Shape& shape = scene.shapes[hit.shape];
    if (const auto* sphere = std::get_if<Sphere>(&shape.geometry)) {
        // The float t of a distant hit carries an error of about |t| * 2^-24, which
        // can be large against a small radius; the crossing is solved again in double
        // precision (the root nearest the reported t) and projected onto the sphere.
        const SphereGeometry geometry{glm::dvec3(sphere->center), static_cast<double>(sphere->radius), false,
                                       sphere->center, sphere->radius};
        const glm::dvec3 o(ray.origin), d(ray.direction);
        double t = hit.t, t0, t1;
        if (solveSphere(geometry, o, d, &t0, &t1)) t = std::abs(t0 - hit.t) <= std::abs(t1 - hit.t) ? t0 : t1;
        const glm::dvec3 offset = o + t * d - geometry.center;
        const double length = glm::length(offset);
        const Vec3 outward = length > 0.0 ? Vec3(offset / length) : Vec3(0.0f, 0.0f, 1.0f);
        sp.p = sphere->center + sphere->radius * outward;
        sp.ng = shape.flipNormals ? -outward : outward;
        sp.ns = sp.ng;
        // Spherical coordinates of the outward direction, as Mitsuba's sphere:
        // u = phi / 2pi with phi in [0, 2pi), v = theta / pi from the +z pole.
        const Vec3 local = sphere->worldToObject * outward;
        float phi = std::atan2(local.y, local.x);
        if (phi < 0.0f) phi += 2.0f * kPi;
        sp.uv = Vec2(phi * kInv2Pi, std::acos(std::clamp(local.z, -1.0f, 1.0f)) * kInvPi);
        return sp;
    }

    if (const auto* mesh = std::get_if<TriangleMesh>(&shape.geometry)) {
        meshSurface(*mesh, hit, sp);
        return sp;
    }

    const TriangleCorners c = cornersOf(shape, hit.primitive);
    const auto* instance = std::get_if<MeshInstance>(&shape.geometry);
    sp.mesh = instance ? instance->mesh.get() : &std::get<TriangleMesh>(shape.geometry);
    sp.triangle = hit.primitive;
    sp.barycentric = hit.barycentric;
    const float b1 = hit.barycentric.x, b2 = hit.barycentric.y, b0 = 1.0f - b1 - b2;
    const Vec3& p0 = c.p[0];
    const Vec3& p1 = c.p[1];
    const Vec3& p2 = c.p[2];
    sp.p = b0 * p0 + b1 * p1 + b2 * p2;
    const Vec3 cross = c.orientation * glm::cross(p1 - p0, p2 - p0);
    const float crossLength = glm::length(cross);
    sp.ng = crossLength > 0.0f ? cross / crossLength : Vec3(0.0f, 0.0f, 1.0f);
    sp.ns = sp.ng;
    if (c.hasNormals) {
        const Vec3 interpolated = b0 * c.n[0] + b1 * c.n[1] + b2 * c.n[2];
        const float nLength = glm::length(interpolated);
        if (nLength > 0.0f && std::isfinite(nLength)) {
            sp.ns = interpolated / nLength;
            if (glm::dot(sp.ns, sp.ng) < 0.0f) sp.ns = -sp.ns;
        }
    }
    // Without texture coordinates the barycentrics serve as a per-triangle parametrisation.
    sp.uv = c.hasUvs ? b0 * c.uv[0] + b1 * c.uv[1] + b2 * c.uv[2] : Vec2(b1, b2);
    return sp;
}

// dp/du and dp/dv of the parametrisation surface() reports uv in: Mitsuba's
// sphere (u = phi / 2pi, v = theta / pi), a mesh's texture coordinates, or the
// barycentrics of meshes without them.
std::pair<Vec3, Vec3> surfaceDerivatives(const Shape& shape, const Hit& hit, const SurfacePoint& sp) {
    if (const auto* sphere = std::get_if<Sphere>(&shape.geometry)) {
        const Vec3 local = (sp.p - sphere->center) / sphere->radius;
        const float sinTheta = std::sqrt(std::max(0.0f, 1.0f - local.z * local.z));
        const float phi = 2.0f * kPi * sp.uv.x;
        const Vec3 dpdu = 2.0f * kPi * sphere->radius * Vec3(-local.y, local.x, 0.0f);
        const Vec3 dpdv = kPi * sphere->radius * Vec3(local.z * std::cos(phi), local.z * std::sin(phi), -sinTheta);
        return {dpdu, dpdv};
    }
    const TriangleMesh& mesh = std::get<TriangleMesh>(shape.geometry);
    const std::size_t base = 3 * static_cast<std::size_t>(hit.primitive);
    const std::uint32_t i0 = mesh.indices[base], i1 = mesh.indices[base + 1], i2 = mesh.indices[base + 2];
    const Vec3 dp1 = mesh.positions[i1] - mesh.positions[i0], dp2 = mesh.positions[i2] - mesh.positions[i0];
    if (mesh.uvs.empty()) return {dp1, dp2};
    const Vec2 duv1 = mesh.uvs[i1] - mesh.uvs[i0], duv2 = mesh.uvs[i2] - mesh.uvs[i0];
    const float determinant = duv1.x * duv2.y - duv1.y * duv2.x;
    if (!(std::abs(determinant) > 1e-12f)) {
        const Frame any(sp.ns);
        return {any.s, any.t};
    }
    // Solve [dp1 dp2] = [dpdu dpdv] [duv1 duv2] for the two tangents.
    return {(duv2.y * dp1 - duv1.y * dp2) / determinant, (duv1.x * dp2 - duv2.x * dp1) / determinant};
}

// Bump and normal maps replace the interpolated shading normal (Bsdf::perturbedNormal).
void applyNormalPerturbation(const Scene& scene, const Hit& hit, SurfacePoint& sp) {
    const Shape& shape = scene.shapes[hit.shape];
    if (shape.bsdf < 0) return;
    const Bsdf& bsdf = *scene.bsdfs[static_cast<std::size_t>(shape.bsdf)];
    if (!bsdf.perturbsNormal()) return;
    ShadingGeometry geometry;
    std::tie(geometry.dpdu, geometry.dpdv) = surfaceDerivatives(shape, hit, sp);
    geometry.frame = Frame(sp.ns);
    const Vec3 s = geometry.dpdu - glm::dot(geometry.dpdu, sp.ns) * sp.ns;
    if (const float length = glm::length(s); length > 0.0f) {
        geometry.frame.s = s / length;
        geometry.frame.t = glm::cross(sp.ns, geometry.frame.s);
    }
    geometry.ng = sp.ng;
    geometry.uv = sp.uv;
    sp.ns = bsdf.perturbedNormal(geometry);
}

}  // namespace

SurfacePoint RayQuery::surface(const Ray& ray, const Hit& hit) const {
    SurfacePoint sp = interpolatedSurface(scene_, ray, hit);
    if (hit.valid()) applyNormalPerturbation(scene_, hit, sp);
    return sp;
}

Vec3 RayQuery::shadingNormalDifferential(const Ray& ray, const Hit& hit, const Vec3& dp) const {
    if (!hit.valid()) return Vec3(0.0f);
    const Shape& shape = scene_.shapes[hit.shape];
    if (const auto* sphere = std::get_if<Sphere>(&shape.geometry)) {
        // n = (p - c) / r, so dn = dp / r; only the tangential part of dp moves along the sphere.
        const Vec3 outward = surface(ray, hit).ng * (shape.flipNormals ? -1.0f : 1.0f);
        const Vec3 tangential = dp - glm::dot(dp, outward) * outward;
        return tangential * ((shape.flipNormals ? -1.0f : 1.0f) / sphere->radius);
    }

    const TriangleCorners c = cornersOf(shape, hit.primitive);
    if (!c.hasNormals) return Vec3(0.0f);
    const float b1 = hit.barycentric.x, b2 = hit.barycentric.y, b0 = 1.0f - b1 - b2;
    const Vec3 interpolated = b0 * c.n[0] + b1 * c.n[1] + b2 * c.n[2];
    const float nLength = glm::length(interpolated);
    if (!(nLength > 0.0f) || !std::isfinite(nLength)) return Vec3(0.0f);
    const Vec3 ns = interpolated / nLength;
    const Vec3 e1 = c.p[1] - c.p[0];
    const Vec3 e2 = c.p[2] - c.p[0];
    // surface() flips the interpolated normal into the geometric normal's hemisphere.
    const float side = glm::dot(ns, c.orientation * glm::cross(e1, e2)) < 0.0f ? -1.0f : 1.0f;
    // Barycentric changes of the offset: least squares of dp = e1 db1 + e2 db2
    // (exact for a dp in the triangle's plane).
    const float a11 = glm::dot(e1, e1), a12 = glm::dot(e1, e2), a22 = glm::dot(e2, e2);
    const float r1 = glm::dot(e1, dp), r2 = glm::dot(e2, dp);
    const float determinant = a11 * a22 - a12 * a12;
    if (!(determinant > 0.0f)) return Vec3(0.0f);
    const float db1 = (a22 * r1 - a12 * r2) / determinant;
    const float db2 = (a11 * r2 - a12 * r1) / determinant;
    const Vec3 dInterpolated = db1 * (c.n[1] - c.n[0]) + db2 * (c.n[2] - c.n[0]);
    // Derivative of N / |N|: the part of dN perpendicular to the unit normal, over |N|.
    return side * (dInterpolated - glm::dot(ns, dInterpolated) * ns) / nLength;
}

}  // namespace fg
