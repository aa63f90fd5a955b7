// Saving pipeline buffers to files and loading them back, so that a run can
// reuse a photon map, an index or a film made by an earlier one. Every buffer
// type has a codec (registered in one table by type name) that writes its
// scalars, strings and arrays through a CodecWriter and reads them back
// through a CodecReader.
//
// File layout (version 1, little-endian):
//   "FGBUF", u32 format version,
//   string type name,
//   u32 column count, per column: string name, u32 element size, u64 element count,
//   u64 item count, string job text,
//   payload: the codec's scalars and strings, and the columns' bytes, in the
//   order the codec wrote them.
// A string is a u32 byte count and the bytes. The header lists every column
// so that a file's contents can be inspected without its codec, and so that
// the reader can check, before allocating anything, that the file holds all
// the bytes the columns claim.
#pragma once

#include "engine/core/error.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"

#include <bit>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace fg {

static_assert(std::endian::native == std::endian::little, "buffer files are written in the host's byte order");

inline constexpr char kBufferFileMagic[5] = {'F', 'G', 'B', 'U', 'F'};
inline constexpr std::uint32_t kBufferFormatVersion = 1;

// One array of a buffer file, as its header lists it.
struct CodecColumn {
    std::string name;
    std::uint32_t elementSize = 0;  // bytes
    std::uint64_t count = 0;        // elements
};

// Collects what a codec writes. Column data is not copied: the arrays passed
// to writeVector and writeSoa must stay alive until the file is written
// (they belong to the buffer being saved, so they do).
class CodecWriter {
public:
    CodecWriter() = default;
    CodecWriter(const CodecWriter&) = delete;
    CodecWriter& operator=(const CodecWriter&) = delete;

    // A scalar: an arithmetic value (bool as one byte 0 or 1).
    template <class T>
    void write(T value) {
        static_assert(std::is_arithmetic_v<T>, "write() takes arithmetic scalars; arrays go through writeVector");
        if constexpr (std::is_same_v<T, bool>) {
            write<std::uint8_t>(value ? 1 : 0);
        } else {
            char bytes[sizeof(T)];
            std::memcpy(bytes, &value, sizeof(T));
            appendOwned(bytes, sizeof(T));
        }
    }
    void writeString(std::string_view text);
    // A named array of trivially copyable elements, listed as a column in the header.
    template <class T>
    void writeVector(const std::string& name, std::span<const T> values) {
        static_assert(std::is_trivially_copyable_v<T> && !std::is_same_v<T, bool>);
        addColumn(name, sizeof(T), values.size(), values.data());
    }
    template <class T>
    void writeVector(const std::string& name, const std::vector<T>& values) {
        writeVector(name, std::span<const T>(values));
    }
    // Every column of the buffer, named "<prefix>.<column name>".
    template <class... Columns>
    void writeSoa(const std::string& prefix, const SoaBuffer<Columns...>& buffer) {
        (writeVector(prefix + "." + Columns::name, buffer.template column<Columns>()), ...);
    }
    // Keeps `value` until the payload is written and returns it: columns a
    // codec computes while saving (a buffer's stored form) are written from it.
    template <class T>
    const T& own(T value) {
        auto held = std::make_shared<const T>(std::move(value));
        const T& kept = *held;
        owned_.push_back(std::move(held));
        return kept;
    }
    // The buffer's item count for the header (photons, vertices, pixels, ...).
    void setItemCount(std::uint64_t items) { items_ = items; }

    std::uint64_t itemCount() const { return items_; }
    const std::vector<CodecColumn>& columns() const { return columns_; }
    // The payload's bytes outside the columns: scalars and strings, version included.
    std::uint64_t scalarBytes() const;
    // Writes the payload; returns false if the stream failed.
    bool writePayload(std::ostream& out) const;

private:
    // A run of payload bytes: owned (scalars, strings) or borrowed (column data).
    struct Piece {
        std::vector<char> owned;
        const void* borrowed = nullptr;
        std::size_t borrowedBytes = 0;
    };
    void appendOwned(const void* bytes, std::size_t size);
    void addColumn(const std::string& name, std::size_t elementSize, std::size_t count, const void* data);

    std::vector<Piece> pieces_;
    std::vector<CodecColumn> columns_;
    std::uint64_t items_ = 0;
    std::vector<std::shared_ptr<const void>> owned_;
};

// Reads a buffer file: the header when constructed, then the payload as the
// codec asks for it. Every length is checked against the bytes left in the
// file before anything is allocated; every failure is an InputError
// "<path>: <what>" on one line.
class CodecReader {
public:
    // Opens the file and reads its header.
    explicit CodecReader(const std::string& path);
    CodecReader(const CodecReader&) = delete;
    CodecReader& operator=(const CodecReader&) = delete;

    const std::string& path() const { return path_; }
    const std::string& type() const { return type_; }
    const std::string& jobText() const { return jobText_; }
    std::uint64_t itemCount() const { return items_; }
    const std::vector<CodecColumn>& columns() const { return columns_; }
    // Bytes of the file not read yet.
    std::uint64_t remaining() const { return remaining_; }
    // The bytes of every column the header lists.
    std::uint64_t columnBytes() const { return columnBytes_; }

    template <class T>
    T read() {
        static_assert(std::is_arithmetic_v<T>, "read() returns arithmetic scalars; arrays go through readVector");
        if constexpr (std::is_same_v<T, bool>) {
            const std::uint8_t byte = read<std::uint8_t>();
            if (byte > 1) fail("corrupt flag value " + std::to_string(byte));
            return byte == 1;
        } else {
            T value;
            readBytes(&value, sizeof(T));
            return value;
        }
    }
    std::string readString();
    // The next column, which must be called `name` and hold elements of sizeof(T) bytes.
    template <class T>
    std::vector<T> readVector(std::string_view name) {
        static_assert(std::is_trivially_copyable_v<T> && !std::is_same_v<T, bool>);
        const CodecColumn& column = expectColumn(name, sizeof(T));
        std::vector<T> values(static_cast<std::size_t>(column.count));
        readColumnBytes(values.data(), column);
        return values;
    }
    // The next columns, one per column of the buffer, named "<prefix>.<column
    // name>", with the declared element sizes and one common count.
    template <class... Columns>
    void readSoa(const std::string& prefix, SoaBuffer<Columns...>& out) {
        std::uint64_t count = 0;
        bool counted = false;
        std::size_t at = nextColumn_;
        // All descriptors are checked before the buffer is sized.
        (checkSoaColumn(at++, prefix + "." + Columns::name, sizeof(typename Columns::value_type), count, counted),
         ...);
        out.resize(static_cast<std::size_t>(count));
        (readColumnBytes(out.template column<Columns>().data(),
                         expectColumn(prefix + "." + Columns::name, sizeof(typename Columns::value_type))),
         ...);
    }
    // Throws unless every column and byte of the file was read.
    void finish();
    [[noreturn]] void fail(const std::string& message) const;

private:
    void readBytes(void* out, std::uint64_t size);
    const CodecColumn& expectColumn(std::string_view name, std::size_t elementSize);
    void checkSoaColumn(std::size_t index, const std::string& name, std::size_t elementSize, std::uint64_t& count,
                        bool& counted) const;
    void readColumnBytes(void* out, const CodecColumn& column);
    std::string readHeaderString(const char* what, std::uint64_t maxLength);

    std::string path_;
    std::ifstream in_;
    std::uint64_t remaining_ = 0;  // bytes of the file not read yet
    std::string type_;
    std::string jobText_;
    std::uint64_t items_ = 0;
    std::vector<CodecColumn> columns_;
    std::uint64_t columnBytes_ = 0;
    std::size_t nextColumn_ = 0;
};

struct BufferCodec {
    std::string type;  // BufferTypeName
    std::function<void(const void* buffer, CodecWriter&)> write;
    // For a codec whose layout has changed or may change: its write begins the
    // payload with the layout's version, and this reads that version and
    // refuses (reader.fail) one this build cannot read. Kept apart from `read`
    // so that checking a file (checkBufferFile, used by validate) refuses the
    // same files as loading it without reading the arrays. Empty: no version.
    std::function<void(CodecReader&)> checkVersion;
    // Reads what follows the version; returns a handle with type, data, bytes set.
    std::function<BufferHandle(CodecReader&)> read;
    // The payload's bytes outside the columns (version included), from the
    // header's column list: with the columns' bytes, the size the payload must
    // have, so that checkBufferFile refuses a file cut short (or with bytes
    // appended) without reading it. Saving checks that the codec wrote exactly
    // this many. Empty: only the read can tell.
    std::function<std::uint64_t(std::span<const CodecColumn>)> scalarBytes;
};

// `codec` with scalarBytes set to a fixed count, for a codec whose scalars do
// not depend on the buffer's contents.
BufferCodec withScalarBytes(BufferCodec codec, std::uint64_t bytes);

// The checkVersion of a codec that writes a u32 `supported` first: any other
// version is refused as "<what> of codec version N (this build reads version
// <supported>)".
std::function<void(CodecReader&)> codecVersionCheck(std::uint32_t supported, std::string what);

// A handle owning `value`, as codecs' read functions return it.
template <class T>
BufferHandle makeBufferHandle(T value) {
    auto data = std::make_shared<T>(std::move(value));
    BufferHandle handle;
    handle.type = BufferTypeName<T>::value;
    handle.bytes = [raw = data.get()] { return raw->bytes(); };
    handle.data = std::move(data);
    return handle;
}

// The codec of buffer type T from its typed write and read functions, and for
// a versioned layout its checkVersion (codecVersionCheck).
template <class T, class Write, class Read>
BufferCodec makeBufferCodec(Write write, Read read, std::function<void(CodecReader&)> checkVersion = {}) {
    BufferCodec codec;
    codec.type = BufferTypeName<T>::value;
    codec.write = [write](const void* buffer, CodecWriter& writer) { write(*static_cast<const T*>(buffer), writer); };
    codec.checkVersion = std::move(checkVersion);
    codec.read = [read](CodecReader& reader) { return makeBufferHandle<T>(read(reader)); };
    return codec;
}

// One table, looked up by type; a codec for a type already there replaces it.
void registerCodec(BufferCodec codec);
const BufferCodec* findCodec(const std::string& type);
// Registered types, sorted.
std::vector<std::string> codecTypes();
// The codecs of the engine's own buffer types (engine/buffers/buffer_codecs.cpp).
std::vector<BufferCodec> builtinCodecs();
// Registers builtinCodecs() once; later calls do nothing. Called by every
// function above, so nothing depends on static initialisation order.
void registerBuiltinCodecs();

// Writes atomically (temporary + rename, every write checked). Throws InputError on failure.
void saveBuffer(const BufferHandle& buffer, const std::string& path, const std::string& jobText);
// The same file written to `temporaryPath` only (errors name `path`), for
// outputs committed together (OutputCommit).
void writeBufferFile(const BufferHandle& buffer, const std::string& path, const std::string& temporaryPath,
                     const std::string& jobText);
// Throws InputError("<path>: ...") on one line: missing or unreadable file, not
// a buffer file, unsupported format version, truncated or corrupt, and a type
// other than expectedType (empty: any), naming the buffer `bufferName` if given.
BufferHandle loadBuffer(const std::string& path, const std::string& expectedType, const std::string& bufferName = "");
// Refuses, with loadBuffer's messages, every file that loadBuffer would refuse
// before it reads the arrays: the header, the type, a type without a codec,
// the codec's own version and, for a codec with scalarBytes (every builtin
// one), a payload shorter or longer than the header's columns and the codec's
// scalars make it. The rest of the payload is not read, so arrays that do not
// fit together pass here and are refused when the file is loaded.
void checkBufferFile(const std::string& path, const std::string& expectedType, const std::string& bufferName = "");

struct BufferFileInfo {
    std::string type;
    std::string jobText;
    std::uint64_t items;
    std::vector<std::string> columns;
};
// The header alone; throws as loadBuffer does.
BufferFileInfo readBufferInfo(const std::string& path);

}  // namespace fg
