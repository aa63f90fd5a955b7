// Structure-of-arrays buffers declared column by column once:
//
//   FG_SOA_COLUMN(RayOrigin, Vec3, "origin");
//   FG_SOA_COLUMN(RayPixel, std::uint32_t, "pixel");
//   using RayBuffer = SoaBuffer<RayOrigin, RayPixel>;
//   buffer.column<RayOrigin>()[i] = ...;
//
// A buffer offers bulk resize, typed column spans, an atomic append mode for
// producers running in parallel (reserve capacity, claim slots, commit), and
// byte accounting for the profiler.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <stdexcept>
#include <string>
#include <tuple>
#include <type_traits>
#include <vector>

namespace fg {

#define FG_SOA_COLUMN(Tag, Type, Name)                 \
    struct Tag {                                       \
        using value_type = Type;                       \
        static constexpr const char* name = Name;      \
    }

template <class... Columns>
class SoaBuffer {
public:
    static constexpr std::size_t kColumnCount = sizeof...(Columns);
    static constexpr std::size_t kNoSlot = std::numeric_limits<std::size_t>::max();

    SoaBuffer() = default;
    explicit SoaBuffer(std::size_t n) { resize(n); }
    SoaBuffer(SoaBuffer&& other) noexcept : columns_(std::move(other.columns_)), size_(other.size_) {
        appendCursor_.store(other.appendCursor_.load());
    }
    SoaBuffer& operator=(SoaBuffer&& other) noexcept {
        columns_ = std::move(other.columns_);
        size_ = other.size_;
        appendCursor_.store(other.appendCursor_.load());
        return *this;
    }

    std::size_t size() const { return size_; }
    bool empty() const { return size_ == 0; }

    void resize(std::size_t n) {
        std::apply([n](auto&... col) { (col.resize(n), ...); }, columns_);
        size_ = n;
    }
    void clear() { resize(0); }
    void shrinkToFit() {
        std::apply([](auto&... col) { (col.shrink_to_fit(), ...); }, columns_);
    }

    template <class Column>
    std::span<typename Column::value_type> column() {
        return std::span(columnsByTag<Column>());
    }
    template <class Column>
    std::span<const typename Column::value_type> column() const {
        return std::span(columnsByTagConst<Column>());
    }

    // Atomic append: beginAppend(capacity) makes room for `capacity` more items,
    // claim(n) hands out n consecutive slots from any thread (kNoSlot when full),
    // commitAppend() trims the buffer to what was claimed. Claimed order depends
    // on scheduling; producers that need a deterministic order write to slots
    // derived from their item index instead.
    void beginAppend(std::size_t capacity) {
        appendCursor_.store(size_);
        resize(size_ + capacity);
    }
    std::size_t claim(std::size_t n) {
        // A failed claim must not move the cursor: commitAppend() trims to it, and
        // slots past it were never written.
        std::size_t slot = appendCursor_.load(std::memory_order_relaxed);
        do {
            if (slot > size_ || n > size_ - slot) return kNoSlot;
        } while (!appendCursor_.compare_exchange_weak(slot, slot + n, std::memory_order_relaxed));
        return slot;
    }
    void commitAppend() { resize(std::min(appendCursor_.load(), size_)); }

    // Bytes held (capacity, not just size), for profiling.
    std::size_t bytes() const {
        std::size_t total = 0;
        std::apply([&](const auto&... col) { ((total += col.capacity() * sizeof(col[0])), ...); }, columns_);
        return total;
    }
    static std::array<const char*, kColumnCount> columnNames() { return {Columns::name...}; }

private:
    template <class Column>
    static constexpr std::size_t indexOf() {
        constexpr std::array<bool, kColumnCount> matches{std::is_same_v<Column, Columns>...};
        for (std::size_t i = 0; i < kColumnCount; ++i)
            if (matches[i]) return i;
        return kColumnCount;
    }
    template <class Column>
    auto& columnsByTag() {
        static_assert(indexOf<Column>() < kColumnCount, "column is not part of this buffer");
        return std::get<indexOf<Column>()>(columns_);
    }
    template <class Column>
    const auto& columnsByTagConst() const {
        static_assert(indexOf<Column>() < kColumnCount, "column is not part of this buffer");
        return std::get<indexOf<Column>()>(columns_);
    }

    std::tuple<std::vector<typename Columns::value_type>...> columns_;
    std::size_t size_ = 0;
    std::atomic<std::size_t> appendCursor_{0};
};

}  // namespace fg
