// Structure-of-arrays buffers declared column by column once:
//
//   FG_SOA_COLUMN(RayOrigin, Vec3, "origin");
//   FG_SOA_COLUMN(RayPixel, std::uint32_t, "pixel");
//   using RayBuffer = SoaBuffer<RayOrigin, RayPixel>;
//   buffer.column<RayOrigin>()[i] = ...;
//
// The column list is the only declaration: the record type of one item
// (RayBuffer::Record, a value per column, addressed by tag), the copies
// between records and columns, and the read-only view of all columns are
// derived from it, so producers fill records and consumers read columns
// without naming every column again:
//
//   RayBuffer::Record ray{origin, pixel};        // values in column order
//   ray.get<RayPixel>() = 7;
//   buffer.append(std::span(records));           // records, or types derived from Record
//   buffer.set(i, ray);  ray = buffer.get(i);
//   const RayBuffer::View view = buffer.view();  // spans of all columns
//   view.column<RayOrigin>()[i];
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
#include <ranges>
#include <span>
#include <stdexcept>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

namespace fg {

#define FG_SOA_COLUMN(Tag, Type, Name)                 \
    struct Tag {                                       \
        using value_type = Type;                       \
        static constexpr const char* name = Name;      \
    }

namespace soa_detail {

// Position of Column in Columns..., or sizeof...(Columns) if it is not there.
template <class Column, class... Columns>
constexpr std::size_t indexOf() {
    constexpr std::array<bool, sizeof...(Columns)> matches{std::is_same_v<Column, Columns>...};
    for (std::size_t i = 0; i < sizeof...(Columns); ++i)
        if (matches[i]) return i;
    return sizeof...(Columns);
}

template <class Column, class... Columns>
constexpr std::size_t checkedIndexOf() {
    constexpr std::size_t index = indexOf<Column, Columns...>();
    static_assert(index < sizeof...(Columns), "column is not part of this buffer");
    return index;
}

}  // namespace soa_detail

// One item of a SoaBuffer<Columns...>: a value per column, addressed by the
// column's tag. Producers may derive from it to carry what is not stored
// (e.g. a validity flag); the buffer copies only the columns.
template <class... Columns>
struct SoaRecord {
    SoaRecord() = default;
    // Values in column order.
    SoaRecord(const typename Columns::value_type&... columnValues) : values(columnValues...) {}

    template <class Column>
    typename Column::value_type& get() {
        return std::get<soa_detail::checkedIndexOf<Column, Columns...>()>(values);
    }
    template <class Column>
    const typename Column::value_type& get() const {
        return std::get<soa_detail::checkedIndexOf<Column, Columns...>()>(values);
    }

    std::tuple<typename Columns::value_type...> values{};
};

// Read-only spans of all columns of a SoaBuffer<Columns...>, taken once: cheap
// to copy into parallel loops, and valid until the buffer is resized.
template <class... Columns>
class SoaView {
public:
    using Record = SoaRecord<Columns...>;

    SoaView() = default;
    explicit SoaView(std::span<const typename Columns::value_type>... columnSpans) : columns_(columnSpans...) {}

    std::size_t size() const { return std::get<0>(columns_).size(); }
    bool empty() const { return size() == 0; }

    template <class Column>
    std::span<const typename Column::value_type> column() const {
        return std::get<soa_detail::checkedIndexOf<Column, Columns...>()>(columns_);
    }
    Record get(std::size_t i) const {
        return std::apply([i](const auto&... col) { return Record(col[i]...); }, columns_);
    }

private:
    std::tuple<std::span<const typename Columns::value_type>...> columns_;
};

template <class... Columns>
class SoaBuffer {
public:
    static_assert(sizeof...(Columns) > 0, "a buffer needs at least one column");
    static constexpr std::size_t kColumnCount = sizeof...(Columns);
    using Record = SoaRecord<Columns...>;
    using View = SoaView<Columns...>;
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
    // Room for `n` items in every column without writing them, so that resizing
    // up to `n` later neither reallocates nor fills the memory twice.
    void reserve(std::size_t n) {
        std::apply([n](auto&... col) { (col.reserve(n), ...); }, columns_);
    }
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
    View view() const {
        return std::apply([](const auto&... col) { return View(std::span(col)...); }, columns_);
    }

    // Record <-> columns. set() writes one item in place (slot i < size()), so
    // parallel producers may fill disjoint slots concurrently.
    Record get(std::size_t i) const {
        return std::apply([i](const auto&... col) { return Record(col[i]...); }, columns_);
    }
    void set(std::size_t i, const Record& record) {
        forEachColumnIndex([&]<std::size_t C>() { std::get<C>(columns_)[i] = std::get<C>(record.values); });
    }

    // Copies item `from` to slot `to`, column by column: going through a Record
    // (get, then set) builds it on the stack and reloads it in wider pieces
    // than it was stored in, a store-forwarding stall per item on hot paths
    // such as compacting a queue.
    void copyItem(std::size_t to, std::size_t from) {
        forEachColumnIndex([&]<std::size_t C>() { std::get<C>(columns_)[to] = std::get<C>(columns_)[from]; });
    }

    // Appends one record; returns its index.
    std::size_t append(const Record& record) {
        const std::size_t i = size_;
        resize(i + 1);
        set(i, record);
        return i;
    }
    // Appends records in order: any sized range of Record or of types derived from it.
    template <std::ranges::sized_range Records>
        requires std::is_convertible_v<const std::ranges::range_value_t<Records>&, const Record&>
    void append(const Records& records) {
        const std::size_t first = size_;
        resize(first + static_cast<std::size_t>(std::ranges::size(records)));
        // Column pointers held in locals, so the loop does not reload them after each store.
        auto destination = std::apply([first](auto&... col) { return std::tuple(col.data() + first...); }, columns_);
        std::size_t k = 0;
        for (const Record& record : records) {
            forEachColumnIndex(
                [&]<std::size_t C>() { std::get<C>(destination)[k] = std::get<C>(record.values); });
            ++k;
        }
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
    auto& columnsByTag() {
        return std::get<soa_detail::checkedIndexOf<Column, Columns...>()>(columns_);
    }
    template <class Column>
    const auto& columnsByTagConst() const {
        return std::get<soa_detail::checkedIndexOf<Column, Columns...>()>(columns_);
    }
    // Calls f.template operator()<C>() for every column index C.
    template <class F>
    static void forEachColumnIndex(F&& f) {
        [&]<std::size_t... C>(std::index_sequence<C...>) { (f.template operator()<C>(), ...); }(
            std::index_sequence_for<Columns...>{});
    }

    std::tuple<std::vector<typename Columns::value_type>...> columns_;
    std::size_t size_ = 0;
    std::atomic<std::size_t> appendCursor_{0};
};

}  // namespace fg
