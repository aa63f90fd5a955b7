// Spatial cache of directional distributions (Vorba et al. 2014, §4.3): records
// at surface points, each with a normal, a validity radius, the distance to
// the furthest particle it was trained on, its GMM and the sufficient
// statistics that on-line EM resumes from. A kd-tree over the record positions
// answers the query of Eq. 11.
#pragma once

#include "engine/accel/kdtree.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"
#include "engine/guiding/stepwise_em.h"

#include <cstdint>
#include <optional>
#include <span>
#include <utility>
#include <vector>

namespace fg {

FG_SOA_COLUMN(GuidePosition, Vec3, "position");
FG_SOA_COLUMN(GuideNormal, Vec3, "normal");  // facing the side the distribution describes
FG_SOA_COLUMN(GuideValidityRadius, float, "validity_radius");
FG_SOA_COLUMN(GuideTrainingRadius, float, "training_radius");  // distance to the furthest training particle
FG_SOA_COLUMN(GuideMixture, DirectionalGmm, "gmm");
FG_SOA_COLUMN(GuideStatistics, GmmStatistics, "statistics");
// The training-time decision whether the record's mixture is sampled at all
// (see oneBounceVariance): 1 leaves its points to BSDF sampling alone, as if
// α were 1 there, so a guided path pays only the lookup. A fixed α per
// record keeps the estimator unbiased; the decision is a function of the
// record's training particles, so the same for any thread count.
FG_SOA_COLUMN(GuideBsdfOnly, std::uint32_t, "bsdf_only");
// The estimate the decision was made from: the second moment of a one-bounce
// diffuse estimate (relative to its squared mean) under the guided mixture
// over that under BSDF sampling.
FG_SOA_COLUMN(GuideMomentRatio, float, "moment_ratio");

using GuidingRecordBuffer = SoaBuffer<GuidePosition, GuideNormal, GuideValidityRadius, GuideTrainingRadius,
                                      GuideMixture, GuideStatistics, GuideBsdfOnly, GuideMomentRatio>;

struct GuidingCacheQuery {
    std::uint32_t candidates = 16;  // M of Eq. 11
};

class GuidingCache {
public:
    GuidingRecordBuffer records;
    std::uint64_t trainingPasses = 0;

    // Rebuilds the kd-tree after records were added or moved.
    void rebuildIndex() { tree_.build(records.column<GuidePosition>()); }
    const KdTree& tree() const { return tree_; }
    // A loaded cache takes its index as saved (engine/buffers/buffer_codecs.cpp).
    void restoreIndex(KdTree tree) { tree_ = std::move(tree); }

    // Eq. 11: among the M records nearest to x, the one minimising
    // |x - x_i|² / h + 2 sqrt(1 - n·n_i) (h: distance to the furthest of the M;
    // ties to the lower index). Records facing away (n·n_i <= 0) are skipped:
    // they describe the other side of a surface.
    std::optional<std::uint32_t> select(const Vec3& x, const Vec3& n, const GuidingCacheQuery& query = {}) const;
    // The selected record if x lies inside its validity radius, else nothing.
    std::optional<std::uint32_t> lookup(const Vec3& x, const Vec3& n, const GuidingCacheQuery& query = {}) const;

    // The query guided paths use once the radii are final: among the records
    // whose validity sphere holds x and that face n, the one minimising Eq. 11
    // (h: distance to the furthest of them), ties to the lower index. Eq. 11's
    // M nearby records are here the records that cover x, as in the lazy
    // lookup of irradiance caching that §4.3 follows, found in a uniform grid
    // instead of a kd-tree search per vertex: the M = 2 search was about half
    // of guiding's cost in pt. Needs buildCoverGrid() after the last change to
    // positions or radii.
    std::optional<std::uint32_t> lookupCovering(const Vec3& x, const Vec3& n) const;
    // Lists, per cell of a uniform grid over the records' spheres, the records
    // whose validity sphere reaches into it, in record order. Serial and a
    // function of the records only, so the same for any thread count.
    void buildCoverGrid();
    bool hasCoverGrid() const { return !coverOffsets_.empty(); }
    // Whether record i's mixture can guide (DirectionalGmm::usable) and training
    // did not leave its points to BSDF sampling (GuideBsdfOnly), cached by
    // buildCoverGrid.
    bool usable(std::uint32_t i) const { return cover_[i].usable != 0; }
    // The same with or without a cover grid.
    bool guides(std::uint32_t i) const {
        return hasCoverGrid() ? usable(i)
                              : records.column<GuideBsdfOnly>()[i] == 0 && records.column<GuideMixture>()[i].usable();
    }
    // Whether any record guides: a cache where none does leaves every path to
    // BSDF sampling, and its users may skip the lookups.
    bool anyGuides() const;
    // lookupCovering for a guided path: the record only if it guides. A cell
    // none of whose records guides answers at once (whichever covering record
    // wins there, it does not guide), so where training left all records to
    // BSDF sampling a vertex pays no scan of the cell's list.
    std::optional<std::uint32_t> lookupGuiding(const Vec3& x, const Vec3& n) const;

    std::size_t bytes() const {
        return records.bytes() + tree_.bytes() + (coverOffsets_.size() + coverRecords_.size()) * sizeof(std::uint32_t) +
               cover_.size() * sizeof(CoverRecord) + cellGuides_.size();
    }

private:
    // The cover grid's cell holding x, if any record reaches it.
    std::optional<std::size_t> coverCell(const Vec3& x) const;
    // lookupCovering within one cell's list.
    std::optional<std::uint32_t> scanCell(std::size_t cell, const Vec3& x, const Vec3& n) const;

    KdTree tree_;
    Vec3 gridLo_{0.0f};
    float cellInverse_ = 1.0f;
    int resolution_[3] = {0, 0, 0};
    std::vector<std::uint32_t> coverOffsets_;  // cells + 1 prefix sums into coverRecords_
    std::vector<std::uint32_t> coverRecords_;
    std::vector<std::uint8_t> cellGuides_;  // per cell: whether a record it lists guides
    // What a lookup reads of each record, in one cache line instead of three
    // columns: the scan of a cell's records is the lookup's cost.
    struct CoverRecord {
        Vec3 position;
        float radius2;
        Vec3 normal;
        std::uint32_t usable;
    };
    std::vector<CoverRecord> cover_;
};

template <>
struct BufferTypeName<GuidingCache> {
    static constexpr const char* value = "GuidingCache";
};

// Validity radius of a record (§4.3), see the .cpp for what stands in for the
// unavailable supplement: per-lobe KL radii, their π-weighted harmonic mean,
// clamped to [0.5, 1] x the training radius.
float validityRadius(const DirectionalGmm& gmm, float trainingRadius, float klThreshold);

// Relative variances of the one-bounce estimate of a diffuse surface's
// reflected radiance, ∫ L_i cos, at a record, under BSDF (cosine) sampling
// and under the guided mixture α p_bsdf + (1 - α) p_gmm, estimated from the
// record's training particles (points of its square with weights, which are
// distributed as L_i cos dω).
struct OneBounceVariance {
    double bsdf = 0.0;
    double mixture = 0.0;
};
OneBounceVariance oneBounceVariance(const DirectionalGmm& gmm, std::span<const WeightedPoint> points,
                                    float bsdfProbability);

// Neighbour clamping (Křivánek et al. 2006): r_i <= r_k + |x_i - x_k| over the
// M nearest records k, computed from the radii before the call (so the result
// does not depend on the order records are visited in). Needs a built index.
void clampNeighbourRadii(GuidingCache& cache, std::uint32_t neighbours);

}  // namespace fg
