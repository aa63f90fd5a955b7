// Deterministic random streams. Every stream is keyed by (seed, pass, item):
// the pass part is the hash of the pass instance's name, which for an instance
// of a repeat block includes its iteration ("train[7].photon"); the item is the
// index of the work item (pixel sample, photon, ...) inside the pass, so the
// numbers an item sees never depend on which thread runs it or in which order
// chunks are scheduled. The generator is PCG32 (O'Neill 2014) whose
// state and stream selector are derived from the key by SplitMix64 finalisers.
#pragma once

#include <glm/vec2.hpp>

#include <cstdint>
#include <string_view>

namespace fg::jobs {

inline constexpr std::uint64_t splitmix64(std::uint64_t x) {
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

// Stable 64-bit key of a pass instance name (FNV-1a), the `pass` part of a stream key.
inline constexpr std::uint64_t streamKey(std::string_view name) {
    std::uint64_t h = 0xCBF29CE484222325ull;
    for (char c : name) {
        h ^= static_cast<unsigned char>(c);
        h *= 0x100000001B3ull;
    }
    return h;
}

class Rng {
public:
    Rng() = default;
    Rng(std::uint64_t seed, std::uint64_t pass, std::uint64_t item) {
        const std::uint64_t k = splitmix64(splitmix64(seed ^ splitmix64(pass)) ^ item);
        inc_ = (splitmix64(k ^ 0xDA942042E4DD58B5ull) << 1u) | 1u;
        state_ = 0;
        nextU32();
        state_ += k;
        nextU32();
    }

    std::uint32_t nextU32() {
        const std::uint64_t old = state_;
        state_ = old * 6364136223846793005ull + inc_;
        const auto xorshifted = static_cast<std::uint32_t>(((old >> 18u) ^ old) >> 27u);
        const auto rot = static_cast<std::uint32_t>(old >> 59u);
        return (xorshifted >> rot) | (xorshifted << ((32u - rot) & 31u));
    }

    // Uniform float in [0, 1): 24 random mantissa bits, never exactly 1.
    float uniform() { return static_cast<float>(nextU32() >> 8) * 0x1p-24f; }
    glm::vec2 uniform2() {
        const float a = uniform();
        const float b = uniform();
        return {a, b};
    }
    // Uniform integer in [0, n) by Lemire's multiply-shift (bias < 2^-32 * n).
    std::uint32_t uniformIndex(std::uint32_t n) {
        return static_cast<std::uint32_t>((static_cast<std::uint64_t>(nextU32()) * n) >> 32);
    }

private:
    std::uint64_t state_ = 0;
    std::uint64_t inc_ = 1;
};

}  // namespace fg::jobs
