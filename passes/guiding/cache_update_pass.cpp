// Guiding cache update (`cache_update`), Vorba et al. 2014 §4.1-4.3 (Fig. 2 d-e):
// every record takes the N nearest particles of the latest map; records made
// in this pass are fitted by off-line stepwise EM (Alg. 1, Eqs. 7-10,
// n = min(i, N)), the others continue by on-line stepwise EM (n = i). Records
// are independent, so they are updated in parallel and the result does not
// depend on the thread count. Only particles that scattered before (the
// global map without direct photons) train the cache (§4.1).
//
// Record creation: the paper creates a record wherever a guided path queries
// the cache and finds none (§4.1). Here the query points are the importons of
// the same training pass (the `importon` pass stores the vertices where its
// guided camera paths look the cache up), or, without an importons input, the
// particles themselves. The departure from the paper is the timing: after the
// update, the query points are visited in item order; one that no record
// covers (Eq. 11 and the validity radius) becomes a new record unless an
// earlier new record of this pass covers it (within new_record_spacing x its
// training radius). So creation never depends on scheduling, and paths that
// miss the cache meanwhile use BSDF sampling alone, which stays unbiased.
//
// The same pass trains the importance cache (§4, Fig. 1 loop, step 2) when
// given `importance_training`: the importons that scattered at least once
// (those at the camera's first hit carry importance straight from the camera,
// which no photon needs to be guided towards, as direct photons carry light
// that next-event estimation finds) train it, through a neighbour index the
// pass builds over them, and its records are made where photons query it: at
// the photons of the `photons` input (the previous training pass's, all of
// them, direct ones included: a photon is guided at its first bounce too), or
// at the training importons when there are none yet.
//
// Records made at photons land where photons do, mostly next to the lights:
// on veach-ajar 3203 of 3364 records lay in the lit room behind the door and
// only 161 in the room the camera sees, each fitted to photons from metres
// around. Importons put them on the surfaces the camera's paths reach.
//
// Cost (veach-ajar, 4 passes of 20k photons, N = 64, 2 threads on a loaded
// machine): with a new record covering half its training radius and up to 100
// off-line sweeps (58 on average) the first pass made 10970 records for 6144
// pixels and training took 11.2 CPU s, 3.6x the guided pt pass. A new record
// now covers its whole training radius (the upper clamp of its validity
// radius; what later passes still miss they fill in) and the off-line EM
// stops after 12 sweeps (the paper's Fig. 3 shows 10): 3304 records in the
// first pass and 4.0 CPU s of training.
#include "passes/passes.h"

#include "engine/accel/point_index.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/error.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/guiding/importons.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cmath>
#include <span>
#include <unordered_map>
#include <vector>

namespace fg {

namespace {

struct UpdateSettings {
    std::uint32_t trainingParticles = 250;  // N
    GuidingCacheQuery query;
    float klThreshold = 0.5f;
    float newRecordSpacing = 1.0f;  // × training radius: how far a new record's cover reaches while created
    EmSettings em;
    bool decideByVariance = true;   // guide_decision = "variance"
    float guideBelowRatio = 0.3f;   // guide_moment_ratio
    float decisionBsdfProbability = 0.5f;
    double minGuidingShare = 0.1;   // min_guiding_share
    int decisionSweeps = 2;         // decision_sweeps
    double earlyGuidingShare = 0.05;  // early_guiding_share
    bool radianceCache = true;      // without importance_training
};

// Whether a record's mixture is worth sampling, from its training particles
// (oneBounceVariance). A sampled mixture costs a guided path about 0.5x an
// unguided sample's time on top of it (the lookup, the mixture's sampling and
// density, the light sample's extra pdf; veach-ajar, README), so it pays only
// where it cuts the estimate's variance by more than that. The one-bounce
// estimate stands for the path: its second moment relative to its squared
// mean, 1 + V, counts the rest of the path's variance as the 1, so a mixture
// that cuts a small V (broad light, where even a perfect fit only quarters
// it) gains little, and one that cuts a large V (light through a gap) gains
// almost all of it. Where the ratio of the moments is not below
// guide_moment_ratio, the record's α becomes 1 (BSDF sampling alone), which
// as any fixed per-record α leaves the estimator unbiased: the paper's α
// (§4.1), chosen per record instead of per scene.
void decide(const UpdateSettings& settings, const DirectionalGmm& gmm, std::span<const WeightedPoint> points,
            std::uint32_t& bsdfOnly, float& momentRatio) {
    const OneBounceVariance v = oneBounceVariance(gmm, points, settings.decisionBsdfProbability);
    momentRatio = static_cast<float>((1.0 + v.mixture) / (1.0 + std::max(0.0, v.bsdf)));
    bsdfOnly = settings.decideByVariance && !(momentRatio < settings.guideBelowRatio) ? 1u : 0u;
}

constexpr const char* kGuidingRare = "guiding_rare";

Vec3 facingIncident(const Vec3& normal, const Vec3& incident) {
    return glm::dot(normal, incident) < 0.0f ? -normal : normal;
}

// Per-chunk scratch of trainingPoints, so that a record costs no allocation.
struct TrainingScratch {
    std::vector<WeightedPoint> points;
    std::vector<std::uint32_t> ids;
    std::vector<float> dist2;
};

// What the cache learns from, photons or importons alike: per particle the
// unit direction it arrived from and a scalar weight (a photon's mean power,
// an importon's importance), and the neighbour index over those that train.
struct TrainingParticles {
    std::span<const Vec3> incident;
    std::vector<float> weight;
    const PointIndex* index = nullptr;
};

// The N nearest particles that arrived through the record's hemisphere, as
// points of its square (in scratch.points). Returns the distance to the
// furthest of them (the training radius). Particles from the other side do
// not count towards N: next to a thin wall lit from behind (veach-ajar's
// door, the partition of the tests' occluded room) most of the nearest
// photons lie on the wall's far face, and counting them left a record of the
// dark side a handful of particles to fit, on which its lobes collapsed, and
// a training radius, hence a validity radius, of the wall's thickness. The
// search widens (by the share of candidates found to arrive through the
// hemisphere, up to 64 N candidates) until N have been found.
float trainingPoints(const TrainingParticles& particles, const Vec3& position, const Vec3& normal,
                     std::uint32_t count, TrainingScratch& scratch) {
    std::vector<std::uint32_t>& ids = scratch.ids;
    std::vector<float>& dist2 = scratch.dist2;
    std::vector<WeightedPoint>& points = scratch.points;
    const Frame frame(normal);
    const std::size_t widest = std::size_t{64} * count;
    float radius2 = 0.0f;
    for (std::size_t candidates = count;;) {
        ids.resize(candidates);
        dist2.resize(candidates);
        const std::size_t found = particles.index->nearest(position, candidates, kInfinity, ids, dist2);
        points.clear();
        radius2 = 0.0f;
        for (std::size_t k = 0; k < found && points.size() < count; ++k) {
            const std::optional<Vec2> s = hemisphereToSquare(frame.toLocal(particles.incident[ids[k]]));
            const float weight = particles.weight[ids[k]];
            if (!s || !(weight > 0.0f)) continue;
            points.push_back({*s, weight});
            radius2 = dist2[k];
        }
        if (points.size() >= count || found < candidates || candidates >= widest) break;
        // Enough candidates for the share of them found to arrive through the
        // hemisphere, and a quarter more: most records miss only a few.
        const std::size_t accepted = std::max<std::size_t>(points.size(), 1);
        candidates = std::min(widest, std::max(candidates + 16, candidates * count * 5 / (4 * accepted)));
    }
    return std::sqrt(radius2);
}

// Where paths query the cache, so where records are made: positions and the
// normal on the side the path arrived from.
struct QueryPoints {
    std::vector<Vec3> positions, normals;
};

QueryPoints photonQueryPoints(const PhotonMap& map, bool withDirect) {
    QueryPoints q;
    const auto positions = map.photons.column<PhotonPosition>();
    const auto incident = map.photons.column<PhotonIncident>();
    const auto normals = map.photons.column<PhotonNormal>();
    const auto classes = map.photons.column<PhotonClassColumn>();
    for (std::size_t i = 0; i < map.photons.size(); ++i) {
        if (!withDirect && classes[i] == PhotonClass::Direct) continue;
        q.positions.push_back(positions[i]);
        q.normals.push_back(facingIncident(normals[i], incident[i]));
    }
    return q;
}

QueryPoints importonQueryPoints(const ImportonMap& map, bool withFirstHits) {
    QueryPoints q;
    const auto positions = map.importons.column<ImportonPosition>();
    const auto normals = map.importons.column<ImportonNormal>();
    const auto bounces = map.importons.column<ImportonBounces>();
    for (std::size_t i = 0; i < map.importons.size(); ++i) {
        if (!withFirstHits && bounces[i] == 0) continue;
        q.positions.push_back(positions[i]);
        q.normals.push_back(normals[i]);
    }
    return q;
}

// This pass's new records, to test later query points against them in item
// order. A record goes to the level of a hierarchy of uniform grids whose
// cells are at least twice its cover's radius, so it touches at most 8 cells
// whatever its size; a query looks at one cell per level in use. (One grid of
// fine cells made records trained from sparse photons, covering metres, touch
// thousands of cells each: 12 % of a veach-ajar run's time.)
class NewRecordGrid {
public:
    explicit NewRecordGrid(float cell) : base_(cell) {}
    void insert(std::uint32_t record, const Vec3& p, float radius) {
        int level = 0;
        while (level + 1 < kLevels && cellSize(level) < 2.0f * radius) ++level;
        used_ |= 1u << level;
        const auto lo = cellOf(p - Vec3(radius), level), hi = cellOf(p + Vec3(radius), level);
        for (long x = lo[0]; x <= hi[0]; ++x)
            for (long y = lo[1]; y <= hi[1]; ++y)
                for (long z = lo[2]; z <= hi[2]; ++z) cells_[key(level, x, y, z)].push_back(record);
    }
    template <class F>
    bool anyCovers(const Vec3& p, F&& covers) const {
        for (int level = 0; level < kLevels; ++level) {
            if (!(used_ & (1u << level))) continue;
            const auto c = cellOf(p, level);
            const auto it = cells_.find(key(level, c[0], c[1], c[2]));
            if (it != cells_.end() && std::any_of(it->second.begin(), it->second.end(), covers)) return true;
        }
        return false;
    }

private:
    static constexpr int kLevels = 24;
    float cellSize(int level) const { return std::ldexp(base_, level); }
    std::array<long, 3> cellOf(const Vec3& p, int level) const {
        const float cell = cellSize(level);
        return {static_cast<long>(std::floor(p.x / cell)), static_cast<long>(std::floor(p.y / cell)),
                static_cast<long>(std::floor(p.z / cell))};
    }
    // Coordinates wrap at 2^19 cells; two cells sharing a key only cost the
    // exact cover test a few more candidates.
    static std::uint64_t key(int level, long x, long y, long z) {
        return (static_cast<std::uint64_t>(level) << 57) | (static_cast<std::uint64_t>(x & 0x7FFFF) << 38) |
               (static_cast<std::uint64_t>(y & 0x7FFFF) << 19) | static_cast<std::uint64_t>(z & 0x7FFFF);
    }
    float base_;
    std::uint32_t used_ = 0;
    std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> cells_;
};

class CacheUpdatePass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const PassParams& params = ctx.params();
        UpdateSettings settings;
        settings.trainingParticles = static_cast<std::uint32_t>(params.getInt("training_particles"));
        settings.query.candidates = static_cast<std::uint32_t>(params.getInt("candidates"));
        settings.klThreshold = static_cast<float>(params.getFloat("kl_threshold"));
        settings.newRecordSpacing = static_cast<float>(params.getFloat("new_record_spacing"));
        settings.em.tolerance = params.getFloat("tolerance");
        settings.em.maxSweeps = static_cast<int>(params.getInt("max_sweeps"));
        settings.em.stepExponent = params.getFloat("step_exponent");
        settings.em.mStepInterval = static_cast<int>(params.getInt("m_step_interval"));
        settings.em.priorA = params.getFloat("prior_a");
        settings.em.priorB = params.getFloat("prior_b");
        settings.em.priorNu = params.getFloat("prior_nu");
        settings.em.effectiveCount = params.getString("prior_count") == "effective";
        settings.decideByVariance = params.getString("guide_decision") == "variance";
        settings.guideBelowRatio = static_cast<float>(params.getFloat("guide_moment_ratio"));
        settings.decisionBsdfProbability = static_cast<float>(params.getFloat("decision_bsdf_probability"));
        settings.minGuidingShare = params.getFloat("min_guiding_share");
        settings.decisionSweeps = static_cast<int>(params.getInt("decision_sweeps"));
        settings.earlyGuidingShare = params.getFloat("early_guiding_share");

        const bool importance = ctx.hasInput("importance_training");
        // Only a radiance cache: its cost is paid in the rendering pass, the
        // budget guiding must earn back, and its query points (this pass's
        // importons) are where that pass looks it up. An importance cache's
        // first pass has only the importons to stand for the photons that will
        // query it, which gave 4-13 % in the occluded room and on veach-ajar,
        // scenes where it guides later passes' photons.
        settings.radianceCache = !importance;
        if (!importance && !(ctx.hasInput("photons") && ctx.hasInput("index")))
            throw InputError("pass '" + ctx.instanceName() +
                                 "': bind `photons` and `index` (a radiance cache), or `importance_training` "
                                 "(an importance cache)");
        GuidingCache& cache = ctx.createOutput<GuidingCache>("cache");
        if (ctx.hasInput("previous")) {
            const GuidingCache& previous = ctx.input<GuidingCache>("previous");
            cache.records.resize(previous.records.size());
            for (std::size_t i = 0; i < previous.records.size(); ++i) cache.records.set(i, previous.records.get(i));
            cache.trainingPasses = previous.trainingPasses;
            cache.rebuildIndex();
        }
        ++cache.trainingPasses;

        TrainingParticles particles;
        QueryPoints queries;
        PointIndex importonIndex;
        if (importance) {
            const ImportonMap& importons = ctx.input<ImportonMap>("importance_training");
            const auto bounces = importons.importons.column<ImportonBounces>();
            std::vector<std::uint32_t> scattered;
            for (std::size_t i = 0; i < bounces.size(); ++i)
                if (bounces[i] > 0) scattered.push_back(static_cast<std::uint32_t>(i));
            importonIndex.build(importons.importons.column<ImportonPosition>(), std::move(scattered));
            particles.incident = importons.importons.column<ImportonIncident>();
            const auto weights = importons.importons.column<ImportonWeight>();
            particles.weight.assign(weights.begin(), weights.end());
            particles.index = &importonIndex;
            queries = ctx.hasInput("photons") ? photonQueryPoints(ctx.input<PhotonMap>("photons"), true)
                                              : importonQueryPoints(importons, false);
        } else {
            const PhotonMap& map = ctx.input<PhotonMap>("photons");
            particles.incident = map.photons.column<PhotonIncident>();
            const auto power = map.photons.column<PhotonPower>();
            particles.weight.resize(power.size());
            for (std::size_t i = 0; i < power.size(); ++i)
                particles.weight[i] = (power[i].x + power[i].y + power[i].z) / 3.0f;
            particles.index = &ctx.input<PointIndex>("index");
            queries = ctx.hasInput("importons") ? importonQueryPoints(ctx.input<ImportonMap>("importons"), true)
                                                : photonQueryPoints(map, false);
        }
        ctx.addCounter("training_particles_indexed", static_cast<std::int64_t>(particles.index->size()));
        if (particles.index->empty()) return;
        update(cache, particles, queries, settings, ctx);
    }

    static void update(GuidingCache& cache, const TrainingParticles& particles, const QueryPoints& queries,
                       const UpdateSettings& settings, PassContext& ctx) {
        const std::size_t existing = cache.records.size();
        // On-line stepwise EM for the records that were there before this map.
        jobs::parallelForChunks(existing, 16, [&](jobs::IndexRange r) {
            TrainingScratch scratch;
            auto positions = cache.records.column<GuidePosition>();
            auto normals = cache.records.column<GuideNormal>();
            auto gmms = cache.records.column<GuideMixture>();
            auto stats = cache.records.column<GuideStatistics>();
            auto radii = cache.records.column<GuideValidityRadius>();
            const auto training = cache.records.column<GuideTrainingRadius>();
            auto bsdfOnly = cache.records.column<GuideBsdfOnly>();
            auto momentRatio = cache.records.column<GuideMomentRatio>();
            for (std::size_t i = r.begin; i != r.end; ++i) {
                trainingPoints(particles, positions[i], normals[i], settings.trainingParticles, scratch);
                onlineStepwiseEm(gmms[i], stats[i], scratch.points, settings.em);
                radii[i] = validityRadius(gmms[i], training[i], settings.klThreshold);
                decide(settings, gmms[i], scratch.points, bsdfOnly[i], momentRatio[i]);
            }
        });
        if (existing > 0) {
            cache.rebuildIndex();
            clampNeighbourRadii(cache, settings.query.candidates);
            // Misses are judged by the query guided paths will make.
            cache.buildCoverGrid();
        }

        const std::vector<Vec3>& queryPositions = queries.positions;
        const std::vector<Vec3>& queryNormals = queries.normals;

        // Misses against the records as they stand, decided in parallel per query point.
        const std::size_t queryCount = queryPositions.size();
        std::vector<std::uint8_t> missed(queryCount, 0);
        jobs::parallelForChunks(queryCount, 1024, [&](jobs::IndexRange r) {
            for (std::size_t q = r.begin; q != r.end; ++q)
                missed[q] = (cache.hasCoverGrid() ? cache.lookupCovering(queryPositions[q], queryNormals[q])
                                                  : cache.lookup(queryPositions[q], queryNormals[q], settings.query))
                                ? 0
                                : 1;
        });

        // New records in item order; each skips query points an earlier one covers.
        Vec3 lo(kInfinity), hi(-kInfinity);
        for (const Vec3& p : queryPositions) {
            lo = glm::min(lo, p);
            hi = glm::max(hi, p);
        }
        NewRecordGrid grid(std::max(1e-6f, glm::length(hi - lo) / 128.0f));
        TrainingScratch creationScratch;
        struct Fresh {
            Vec3 position, normal;
            float trainingRadius;
            std::size_t firstPoint;  // its training points in freshPoints
        };
        std::vector<Fresh> fresh;
        // The training points found while deciding a new record's cover are
        // kept for its fit instead of being searched for a second time.
        std::vector<WeightedPoint> freshPoints;
        for (std::size_t q = 0; q < queryCount; ++q) {
            if (!missed[q]) continue;
            const Vec3 p = queryPositions[q];
            const Vec3 n = queryNormals[q];
            const bool covered = grid.anyCovers(p, [&](std::uint32_t k) {
                const float r = settings.newRecordSpacing * fresh[k].trainingRadius;
                return glm::dot(n, fresh[k].normal) > 0.0f && KdTree::distance2(p, fresh[k].position) <= r * r;
            });
            if (covered) continue;
            const float radius = trainingPoints(particles, p, n, settings.trainingParticles, creationScratch);
            if (!(radius > 0.0f)) continue;
            grid.insert(static_cast<std::uint32_t>(fresh.size()), p, settings.newRecordSpacing * radius);
            fresh.push_back({p, n, radius, freshPoints.size()});
            freshPoints.insert(freshPoints.end(), creationScratch.points.begin(), creationScratch.points.end());
        }

        // Off-line stepwise EM for the new records, in parallel: each goes on
        // until it settles or has run sweepLimit sweeps in all, and its record
        // is written from where its fit stands.
        cache.records.resize(existing + fresh.size());
        std::vector<DirectionalGmm> freshGmms(fresh.size());
        std::vector<GmmStatistics> freshStats(fresh.size());
        std::vector<OfflineEmProgress> progress(fresh.size());
        const auto fitFresh = [&](int sweepLimit) {
            jobs::parallelForChunks(fresh.size(), 8, [&](jobs::IndexRange r) {
                for (std::size_t k = r.begin; k != r.end; ++k) {
                    const std::size_t end = k + 1 < fresh.size() ? fresh[k + 1].firstPoint : freshPoints.size();
                    const std::span<const WeightedPoint> points(freshPoints.data() + fresh[k].firstPoint,
                                                                end - fresh[k].firstPoint);
                    const float radius = fresh[k].trainingRadius;
                    if (progress[k].sweeps == 0) freshGmms[k] = initialGmm(points, settings.em);
                    continueOfflineStepwiseEm(freshGmms[k], freshStats[k], progress[k], points, settings.em, sweepLimit);
                    GuidingRecordBuffer::Record record;
                    record.get<GuidePosition>() = fresh[k].position;
                    record.get<GuideNormal>() = fresh[k].normal;
                    record.get<GuideTrainingRadius>() = radius;
                    record.get<GuideMixture>() = freshGmms[k];
                    record.get<GuideStatistics>() = freshStats[k];
                    record.get<GuideValidityRadius>() = validityRadius(freshGmms[k], radius, settings.klThreshold);
                    decide(settings, freshGmms[k], points, record.get<GuideBsdfOnly>(), record.get<GuideMomentRatio>());
                    cache.records.set(existing + k, record);
                }
            });
            cache.rebuildIndex();
            clampNeighbourRadii(cache, settings.query.candidates);
            cache.buildCoverGrid();
        };
        // The scene-wide half of the decision: where few of the paths'
        // vertices find a guiding record, guiding cannot pay for what it costs
        // every path. This pass's importons stand for those vertices, so the
        // share counts records by how often paths reach them, not by their
        // number: new records keep being made where paths rarely go, which
        // lowered the records' share on veach-ajar and in the tests' occluded
        // room pass after pass (28 to 19 %, 23 to 11 %) while the importons'
        // held or grew (19-26 % to 28-34 %, 21 to 23 %). A few guiding records
        // with wide validity radii still make the paths look the cache up in
        // much of the scene: on the Cornell box (report job, 64x48) 13 of 199
        // records, found by 5 % of the importons, guided after the first
        // training pass and cost every sample 1.17-1.18x an unguided one for no
        // measured per-sample gain. Below min_guiding_share no record guides
        // (§4.1's α = 1 at every record, which keeps the estimator unbiased
        // and spares the paths the lookup: a cache that guides nowhere is not
        // looked up) and the pass raises guiding_rare, on which a training
        // block may end.
        const bool shareDecides = settings.decideByVariance && settings.radianceCache;
        const auto guidedQueries = [&] {
            std::vector<std::uint8_t> guided(queryCount, 0);
            jobs::parallelForChunks(queryCount, 1024, [&](jobs::IndexRange r) {
                for (std::size_t q = r.begin; q != r.end; ++q) {
                    const std::optional<std::uint32_t> record =
                        cache.hasCoverGrid() ? cache.lookupCovering(queryPositions[q], queryNormals[q])
                                             : cache.lookup(queryPositions[q], queryNormals[q], settings.query);
                    guided[q] = record && cache.guides(*record) ? 1 : 0;
                }
            });
            std::int64_t n = 0;
            for (std::uint8_t g : guided) n += g;
            return n;
        };
        const auto rareShare = [&](std::int64_t guided, double share) {
            return static_cast<double>(guided) < share * static_cast<double>(queryCount);
        };
        // Where guiding is rare, the first pass's off-line EM was most of
        // training (Cornell box, report job: 0.075 of 0.108 CPU s, nearly
        // every record running all 12 sweeps), to be thrown away. So the share
        // is judged first on fits stopped after decision_sweeps sweeps: below
        // early_guiding_share guiding is rare without finishing them; else the
        // fits are finished (into the ones a single stage makes, bit for bit)
        // and judged against min_guiding_share as before. Under stopped fits
        // fewer query points find a guiding record: report job, first pass, 2 sweeps against 12, seeds 1, 3,
        // 4, 5: Cornell box 1.9-3.2 % against 4.7-5.1 %, veach-ajar 15-19 %
        // against 18-26 %; the tests' occluded room 12 % against 21 %. Hence
        // the early threshold at half the final one: the Cornell box stops
        // early, and the scenes where guiding pays never do. A cache left
        // rare keeps the stopped fits; they guide nowhere.
        const double earlyShare = std::min(settings.earlyGuidingShare, settings.minGuidingShare);
        const bool early = shareDecides && earlyShare > 0.0 && settings.decisionSweeps > 0 &&
                           settings.decisionSweeps < settings.em.maxSweeps && !fresh.empty();
        std::optional<std::int64_t> guided;
        bool rare = false;
        if (early) {
            // The existing records' radii as clamped before the new records
            // came, so that the final clamp starts where a single stage's does.
            const auto radii = cache.records.column<GuideValidityRadius>();
            const std::vector<float> existingRadii(radii.begin(), radii.begin() + static_cast<std::ptrdiff_t>(existing));
            fitFresh(settings.decisionSweeps);
            guided = guidedQueries();
            ctx.addCounter("decision_guided_queries", *guided);
            rare = rareShare(*guided, earlyShare);
            if (!rare) {
                std::copy(existingRadii.begin(), existingRadii.end(), cache.records.column<GuideValidityRadius>().begin());
                fitFresh(settings.em.maxSweeps);
                guided.reset();
            }
        } else {
            fitFresh(settings.em.maxSweeps);
        }
        if (shareDecides && cache.records.size() > 0) {
            if (!guided) {
                guided = guidedQueries();
                rare = rareShare(*guided, settings.minGuidingShare);
            }
            ctx.addCounter("guided_queries", *guided);
            ctx.addCounter("queries", static_cast<std::int64_t>(queryCount));
            if (rare) {
                for (std::uint32_t& flag : cache.records.column<GuideBsdfOnly>()) flag = 1;
                cache.buildCoverGrid();
                ctx.signal(kGuidingRare);
            }
        }
        ctx.addItems(static_cast<std::int64_t>(cache.records.size()));
        ctx.addCounter("records_created", static_cast<std::int64_t>(fresh.size()));
        std::int64_t totalSweeps = 0;
        for (const OfflineEmProgress& p : progress) totalSweeps += p.sweeps;
        ctx.addCounter("offline_em_sweeps", totalSweeps);
        ctx.addCounter("records", static_cast<std::int64_t>(cache.records.size()));
        std::int64_t bsdfOnly = 0;
        for (std::uint32_t flag : cache.records.column<GuideBsdfOnly>()) bsdfOnly += flag;
        ctx.addCounter("records_bsdf_only", bsdfOnly);
    }
};

}  // namespace

PassRegistration cacheUpdatePass() {
    PassSpec spec;
    spec.name = "cache_update";
    spec.doc = "Guiding cache update (Vorba et al. 2014): records fitted to the N nearest particles by stepwise EM";
    SlotSpec previous{"previous", "GuidingCache", "the cache of the previous training pass (absent: an empty cache)"};
    previous.optional = true;
    SlotSpec importonSlot{"importons", "ImportonMap",
                          "where camera paths query the cache: new records are made at the importons no record covers "
                          "(absent: at the particles)"};
    importonSlot.optional = true;
    SlotSpec photonSlot{"photons", "PhotonMap",
                        "the latest photon map: trains a radiance cache; with importance_training, where photons query "
                        "the importance cache (new records are made at the photons no record covers)"};
    photonSlot.optional = true;
    SlotSpec indexSlot{"index", "PointIndex",
                       "neighbour search over the training photons (those that scattered at least once); needed "
                       "without importance_training"};
    indexSlot.optional = true;
    SlotSpec importanceTraining{"importance_training", "ImportonMap",
                               "train an importance cache on these importons (those past the camera's first hit) "
                               "instead of a radiance cache on photons"};
    importanceTraining.optional = true;
    spec.inputs = {photonSlot, indexSlot, previous, importonSlot, importanceTraining};
    spec.outputs = {{"cache", "GuidingCache", "the updated cache of directional GMMs"}};
    spec.params = {
        {"training_particles", ParamType::Int, std::int64_t{250}, 1, 4096, {}, "N: nearest particles per record (Fig. 7)"},
        {"candidates", ParamType::Int, std::int64_t{16}, 1, 64, {},
         "M: nearest records for neighbour clamping, and for Eq. 11 if the cover grid is not built"},
        {"kl_threshold", ParamType::Float, 0.5, 1e-6, 1e6, {}, "KL divergence a lobe may change by within the validity radius"},
        {"tolerance", ParamType::Float, 1e-3, 1e-12, 1.0, {}, "off-line EM stops when a sweep changes the log-likelihood by less than this times max(|L|, total weight)"},
        {"new_record_spacing", ParamType::Float, 1.0, 0.05, 4.0, {},
         "particles within this times a new record's training radius become no record of their own in the same pass"},
        {"max_sweeps", ParamType::Int, std::int64_t{12}, 1, 100000, {},
         "off-line EM ends after this many sweeps over a new record's particles even if not settled"},
        {"step_exponent", ParamType::Float, 0.7, 0.5, 1.0, {}, "stepwise EM step sizes i^-exponent"},
        {"m_step_interval", ParamType::Int, std::int64_t{10}, 1, 100000, {}, "particles between M-steps (m)"},
        {"prior_a", ParamType::Float, 2.01, 2.0, 1e6, {}, "a: covariance prior (Eq. 10)"},
        {"prior_b", ParamType::Float, 5e-4, 0.0, 1e6, {}, "b: covariance prior (Eq. 10)"},
        {"prior_nu", ParamType::Float, 1.01, 1.0, 1e6, {}, "nu: mixing-weight prior (Eq. 9)"},
        {"prior_count", ParamType::String, std::string("effective"), 0, 0, {"particles", "effective"},
         "n of the priors in Eqs. 9-10: the particles' number (the paper) or their effective count n w^2/mean(w^2), "
         "which keeps a lobe from collapsing onto a few heavy particles"},
        {"guide_decision", ParamType::String, std::string("variance"), 0, 0, {"variance", "always"},
         "variance: a record's mixture is sampled only where, by its training particles, it cuts the second moment "
         "of a one-bounce diffuse estimate below guide_moment_ratio x BSDF sampling's (elsewhere its points use "
         "BSDF sampling alone); always: every usable mixture is sampled"},
        {"guide_moment_ratio", ParamType::Float, 0.3, 0.0, 1e6, {},
         "guide_decision = variance: the largest ratio of the guided to the BSDF-sampled second moment at which a "
         "record still guides (below 1 / the cost of a guided sample relative to an unguided one, about 0.6, as "
         "the estimate favours guiding)"},
        {"decision_bsdf_probability", ParamType::Float, 0.5, 0.01, 1.0, {},
         "alpha of the guided mixture the decision assumes (pt's guiding_bsdf_probability)"},
        {"min_guiding_share", ParamType::Float, 0.1, 0.0, 1.0, {},
         "guide_decision = variance, a radiance cache: where fewer than this share of the query points (importons, "
         "or photons without them) find a guiding record after the update, no record guides (every record "
         "bsdf_only, so paths skip the lookup) and the pass raises guiding_rare, on which a training block may end "
         "(0: never; importance caches: never)"},
        {"decision_sweeps", ParamType::Int, std::int64_t{2}, 0, 100000, {},
         "guide_decision = variance, a radiance cache: the share of query points that find a guiding record is "
         "first judged (against early_guiding_share) with the new records' off-line EM stopped after this many "
         "sweeps, and the fits are finished only where guiding is not rare by it (0, or not below max_sweeps: "
         "judged once, on the finished fits)"},
        {"early_guiding_share", ParamType::Float, 0.05, 0.0, 1.0, {},
         "decision_sweeps > 0: where fewer than this share of the query points find a guiding record under the "
         "stopped fits, guiding is rare (as below min_guiding_share) and the fits are left unfinished; at most "
         "min_guiding_share (0: judged on the finished fits only)"},
    };
    spec.signals = {kGuidingRare};
    return {spec, [] { return std::make_unique<CacheUpdatePass>(); }, {}, {}};
}

}  // namespace fg
