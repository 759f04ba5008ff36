// Scratch arrays for the renderer's per-vertex passes, left unconstructed:
// every element a pass reads it has written first, and the default values
// of Vec3 and the like (zeros) would cost stores that nothing reads, 24
// per array of eight Vec3, at every vertex of every path
// (bench/README.md, "A hit's BSDF in lanes").
#pragma once

#include <type_traits>

namespace dofarm::render {

template <class T, int N>
struct Scratch {
  static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>);
  union {
    T v[N];
  };
  Scratch() {}
  T& operator[](int i) { return v[i]; }
  const T& operator[](int i) const { return v[i]; }
  T* data() { return v; }
  const T* data() const { return v; }
};

}  // namespace dofarm::render
