#include "engine/core/soa.h"

#include "jobs/parallel.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <vector>

namespace fg {
namespace {

struct Triple {
    float x = 0.0f, y = 0.0f, z = 0.0f;
};

FG_SOA_COLUMN(ItemId, std::uint32_t, "id");
FG_SOA_COLUMN(ItemWeight, double, "weight");
FG_SOA_COLUMN(ItemPosition, Triple, "position");
using ItemBuffer = SoaBuffer<ItemId, ItemWeight, ItemPosition>;

constexpr std::size_t kRowBytes = sizeof(std::uint32_t) + sizeof(double) + sizeof(Triple);

TEST(SoaBuffer, NamesItsColumnsInDeclarationOrder) {
    static_assert(ItemBuffer::kColumnCount == 3);
    const auto names = ItemBuffer::columnNames();
    EXPECT_STREQ(names[0], "id");
    EXPECT_STREQ(names[1], "weight");
    EXPECT_STREQ(names[2], "position");
}

TEST(SoaBuffer, ColumnsAreAddressedByTagAndIndependent) {
    ItemBuffer buffer(100);
    EXPECT_EQ(buffer.size(), 100u);
    EXPECT_FALSE(buffer.empty());
    auto ids = buffer.column<ItemId>();
    auto weights = buffer.column<ItemWeight>();
    auto positions = buffer.column<ItemPosition>();
    ASSERT_EQ(ids.size(), 100u);
    ASSERT_EQ(weights.size(), 100u);
    ASSERT_EQ(positions.size(), 100u);
    for (std::size_t i = 0; i < 100; ++i) {
        ids[i] = static_cast<std::uint32_t>(3 * i);
        weights[i] = 0.5 * static_cast<double>(i);
        positions[i] = {static_cast<float>(i), -1.0f, 2.0f};
    }
    const ItemBuffer& view = buffer;
    for (std::size_t i = 0; i < 100; ++i) {
        EXPECT_EQ(view.column<ItemId>()[i], 3 * i);
        EXPECT_EQ(view.column<ItemWeight>()[i], 0.5 * static_cast<double>(i));
        EXPECT_EQ(view.column<ItemPosition>()[i].x, static_cast<float>(i));
    }
}

TEST(SoaBuffer, ResizeKeepsThePrefixAndResizesEveryColumn) {
    ItemBuffer buffer(10);
    for (std::size_t i = 0; i < 10; ++i) buffer.column<ItemWeight>()[i] = static_cast<double>(i) + 0.25;
    buffer.resize(1000);
    EXPECT_EQ(buffer.size(), 1000u);
    EXPECT_EQ(buffer.column<ItemId>().size(), 1000u);
    EXPECT_EQ(buffer.column<ItemPosition>().size(), 1000u);
    for (std::size_t i = 0; i < 10; ++i) EXPECT_EQ(buffer.column<ItemWeight>()[i], static_cast<double>(i) + 0.25);
    EXPECT_EQ(buffer.column<ItemWeight>()[999], 0.0);
    buffer.resize(3);
    EXPECT_EQ(buffer.column<ItemWeight>().size(), 3u);
    EXPECT_EQ(buffer.column<ItemWeight>()[2], 2.25);
    buffer.clear();
    EXPECT_TRUE(buffer.empty());
    EXPECT_EQ(buffer.column<ItemId>().size(), 0u);
}

TEST(SoaBuffer, BytesFollowCapacity) {
    ItemBuffer buffer;
    EXPECT_EQ(buffer.bytes(), 0u);
    buffer.resize(100);
    const std::size_t small = buffer.bytes();
    EXPECT_GE(small, 100 * kRowBytes);
    buffer.resize(10000);
    const std::size_t large = buffer.bytes();
    EXPECT_GE(large, 10000 * kRowBytes);
    EXPECT_GT(large, small);
    // Shrinking the size keeps the memory until it is given back.
    buffer.resize(10);
    EXPECT_EQ(buffer.bytes(), large);
    buffer.shrinkToFit();
    EXPECT_EQ(buffer.bytes(), 10 * kRowBytes);
}

TEST(SoaBuffer, MoveTransfersTheColumns) {
    ItemBuffer source(5);
    source.column<ItemId>()[4] = 77;
    ItemBuffer moved(std::move(source));
    EXPECT_EQ(moved.size(), 5u);
    EXPECT_EQ(moved.column<ItemId>()[4], 77u);
    ItemBuffer assigned;
    assigned = std::move(moved);
    EXPECT_EQ(assigned.size(), 5u);
    EXPECT_EQ(assigned.column<ItemId>()[4], 77u);
}

TEST(SoaBuffer, ParallelAppendKeepsEveryItemExactlyOnce) {
    ItemBuffer buffer(7);
    for (std::size_t i = 0; i < 7; ++i) buffer.column<ItemId>()[i] = 1000000 + static_cast<std::uint32_t>(i);
    const std::size_t n = 50000;
    buffer.beginAppend(n);
    // Chunks claim their slots in one go, single items one by one.
    jobs::parallelForChunks(n / 2, 37, [&](jobs::IndexRange r) {
        const std::size_t slot = buffer.claim(r.size());
        ASSERT_NE(slot, ItemBuffer::kNoSlot);
        for (std::size_t k = 0; k < r.size(); ++k) {
            buffer.column<ItemId>()[slot + k] = static_cast<std::uint32_t>(r.begin + k);
            buffer.column<ItemWeight>()[slot + k] = static_cast<double>(r.begin + k);
        }
    });
    jobs::parallelFor(n - n / 2, 11, [&](std::size_t i) {
        const std::size_t slot = buffer.claim(1);
        ASSERT_NE(slot, ItemBuffer::kNoSlot);
        buffer.column<ItemId>()[slot] = static_cast<std::uint32_t>(n / 2 + i);
        buffer.column<ItemWeight>()[slot] = static_cast<double>(n / 2 + i);
    });
    buffer.commitAppend();
    ASSERT_EQ(buffer.size(), 7 + n);
    for (std::size_t i = 0; i < 7; ++i) EXPECT_EQ(buffer.column<ItemId>()[i], 1000000 + i);
    std::vector<int> seen(n, 0);
    for (std::size_t i = 7; i < buffer.size(); ++i) {
        const std::uint32_t id = buffer.column<ItemId>()[i];
        ASSERT_LT(id, n);
        ++seen[id];
        EXPECT_EQ(buffer.column<ItemWeight>()[i], static_cast<double>(id));  // rows stay together
    }
    for (std::size_t id = 0; id < n; ++id) EXPECT_EQ(seen[id], 1) << "item " << id;
}

TEST(SoaBuffer, ClaimPastCapacityFailsAndCommitKeepsOnlyClaimedSlots) {
    ItemBuffer buffer(2);
    buffer.beginAppend(10);
    EXPECT_EQ(buffer.claim(4), 2u);
    EXPECT_EQ(buffer.claim(4), 6u);
    EXPECT_EQ(buffer.claim(4), ItemBuffer::kNoSlot);  // 4 more would need 14 slots
    EXPECT_EQ(buffer.claim(3), ItemBuffer::kNoSlot);
    EXPECT_EQ(buffer.claim(2), 10u);  // what is left can still be handed out
    EXPECT_EQ(buffer.claim(1), ItemBuffer::kNoSlot);
    buffer.commitAppend();
    EXPECT_EQ(buffer.size(), 12u);
}

TEST(SoaBuffer, CommitTrimsToWhatWasClaimed) {
    ItemBuffer buffer;
    buffer.beginAppend(100);
    EXPECT_EQ(buffer.claim(30), 0u);
    EXPECT_EQ(buffer.claim(80), ItemBuffer::kNoSlot);  // a failed claim holds no slots
    buffer.commitAppend();
    EXPECT_EQ(buffer.size(), 30u);
}

TEST(SoaBuffer, ParallelClaimsPastCapacityHandOutExactlyTheCapacity) {
    ItemBuffer buffer;
    const std::size_t capacity = 5000;
    buffer.beginAppend(capacity);
    std::atomic<std::size_t> granted{0};
    jobs::parallelFor(3 * capacity, 13, [&](std::size_t i) {
        const std::size_t slot = buffer.claim(1);
        if (slot == ItemBuffer::kNoSlot) return;
        ASSERT_LT(slot, capacity);
        buffer.column<ItemId>()[slot] = static_cast<std::uint32_t>(i) + 1;
        granted.fetch_add(1);
    });
    buffer.commitAppend();
    EXPECT_EQ(granted.load(), capacity);
    ASSERT_EQ(buffer.size(), capacity);
    for (std::size_t i = 0; i < capacity; ++i) EXPECT_NE(buffer.column<ItemId>()[i], 0u) << "slot " << i;
}

TEST(SoaRecord, HoldsOneValuePerColumnAddressedByTag) {
    ItemBuffer::Record record{7u, 1.5, Triple{1.0f, 2.0f, 3.0f}};
    EXPECT_EQ(record.get<ItemId>(), 7u);
    EXPECT_EQ(record.get<ItemWeight>(), 1.5);
    EXPECT_EQ(record.get<ItemPosition>().z, 3.0f);
    record.get<ItemWeight>() = -2.0;
    const ItemBuffer::Record& constant = record;
    EXPECT_EQ(constant.get<ItemWeight>(), -2.0);
    const ItemBuffer::Record zero;
    EXPECT_EQ(zero.get<ItemId>(), 0u);
    EXPECT_EQ(zero.get<ItemWeight>(), 0.0);
}

TEST(SoaRecord, RoundTripsThroughTheColumns) {
    ItemBuffer buffer(4);
    const ItemBuffer::Record record{42u, 0.25, Triple{-1.0f, 0.5f, 8.0f}};
    buffer.set(2, record);
    EXPECT_EQ(buffer.column<ItemId>()[2], 42u);
    EXPECT_EQ(buffer.column<ItemWeight>()[2], 0.25);
    EXPECT_EQ(buffer.column<ItemPosition>()[2].x, -1.0f);
    EXPECT_EQ(buffer.column<ItemId>()[1], 0u) << "other slots untouched";
    EXPECT_EQ(buffer.column<ItemId>()[3], 0u);
    const ItemBuffer::Record back = buffer.get(2);
    EXPECT_EQ(back.get<ItemId>(), 42u);
    EXPECT_EQ(back.get<ItemWeight>(), 0.25);
    EXPECT_EQ(std::memcmp(&back.get<ItemPosition>(), &record.get<ItemPosition>(), sizeof(Triple)), 0);
}

TEST(SoaBuffer, CopyItemCopiesEveryColumnOfOneSlot) {
    ItemBuffer buffer(3);
    buffer.set(0, ItemBuffer::Record{7u, 1.5, Triple{1.0f, 2.0f, 3.0f}});
    buffer.set(2, ItemBuffer::Record{9u, -2.0, Triple{4.0f, 5.0f, 6.0f}});
    buffer.copyItem(1, 2);
    EXPECT_EQ(buffer.column<ItemId>()[1], 9u);
    EXPECT_EQ(buffer.column<ItemWeight>()[1], -2.0);
    EXPECT_EQ(buffer.column<ItemPosition>()[1].z, 6.0f);
    EXPECT_EQ(buffer.column<ItemId>()[0], 7u) << "other slots untouched";
    EXPECT_EQ(buffer.column<ItemId>()[2], 9u) << "the source stays";
}

// What a producer keeps besides the columns; only the columns are stored.
struct TaggedItem : ItemBuffer::Record {
    bool keep = false;
};

TEST(SoaRecord, AppendCopiesRecordsInOrderAfterWhatIsThere) {
    ItemBuffer buffer(1);
    buffer.column<ItemId>()[0] = 99;
    std::vector<TaggedItem> records(5);
    for (std::size_t i = 0; i < records.size(); ++i) {
        records[i].get<ItemId>() = static_cast<std::uint32_t>(10 + i);
        records[i].get<ItemWeight>() = static_cast<double>(i) / 4.0;
        records[i].get<ItemPosition>() = {static_cast<float>(i), 0.0f, 0.0f};
    }
    buffer.append(std::span(records).first(3));
    ASSERT_EQ(buffer.size(), 4u);
    EXPECT_EQ(buffer.column<ItemId>()[0], 99u);
    for (std::size_t i = 0; i < 3; ++i) {
        EXPECT_EQ(buffer.column<ItemId>()[1 + i], 10 + i);
        EXPECT_EQ(buffer.column<ItemWeight>()[1 + i], static_cast<double>(i) / 4.0);
        EXPECT_EQ(buffer.column<ItemPosition>()[1 + i].x, static_cast<float>(i));
    }
    buffer.append(std::vector<ItemBuffer::Record>{});
    EXPECT_EQ(buffer.size(), 4u);
    EXPECT_EQ(buffer.append(records[4]), 4u) << "one record goes to the end and gives its index";
    ASSERT_EQ(buffer.size(), 5u);
    EXPECT_EQ(buffer.column<ItemId>()[4], 14u);
}

TEST(SoaView, SpansEveryColumnOfTheBuffer) {
    ItemBuffer buffer;
    for (std::uint32_t i = 0; i < 6; ++i) buffer.append(ItemBuffer::Record{i, 2.0 * i, Triple{0.0f, 1.0f * i, 0.0f}});
    const ItemBuffer::View view = buffer.view();
    EXPECT_EQ(view.size(), 6u);
    EXPECT_FALSE(view.empty());
    EXPECT_EQ(view.column<ItemId>().data(), buffer.column<ItemId>().data());
    EXPECT_EQ(view.column<ItemWeight>().data(), buffer.column<ItemWeight>().data());
    EXPECT_EQ(view.column<ItemPosition>().size(), 6u);
    EXPECT_EQ(view.column<ItemWeight>()[5], 10.0);
    const ItemBuffer::Record record = view.get(3);
    EXPECT_EQ(record.get<ItemId>(), 3u);
    EXPECT_EQ(record.get<ItemPosition>().y, 3.0f);
    EXPECT_TRUE(ItemBuffer().view().empty());
}

}  // namespace
}  // namespace fg
