// XXH64 checksums (common/checksum.h): the published vectors, streaming in
// any split, and the file checksum.
#include <gtest/gtest.h>

#include <fstream>
#include <string>
#include <vector>

#include "common/checksum.h"
#include "shard_fixtures.h"

namespace dofarm {
namespace {

using shard_testing::TempDir;

TEST(Checksum, MatchesPublishedXxh64Vectors) {
  // Values from the xxHash reference implementation (seed 0); the 39-byte
  // input exercises the 32-byte stripe loop, the others only the tail.
  EXPECT_EQ(checksum64("", 0), 0xEF46DB3751D8E999ull);
  EXPECT_EQ(checksum64("a", 1), 0xD24EC4F1A98C6E5Bull);
  EXPECT_EQ(checksum64("abc", 3), 0x44BC2CF5AD770999ull);
  const std::string s = "Nobody inspects the spammish repetition";
  EXPECT_EQ(checksum64(s.data(), s.size()), 0xFBCEA83C8A378BF1ull);
}

TEST(Checksum, StreamingEqualsOneShotForEverySplit) {
  std::string data;
  for (int i = 0; i < 150; ++i) data += char(i * 37 + 11);
  for (size_t n = 0; n <= data.size(); n += 7) {
    uint64_t one = checksum64(data.data(), n);
    for (size_t cut = 0; cut <= n; ++cut) {
      Checksum64 c;
      c.update(data.data(), cut);
      c.update(data.data() + cut, 0);
      c.update(data.data() + cut, n - cut);
      ASSERT_EQ(c.digest(), one) << "length " << n << " split at " << cut;
    }
  }
}

TEST(Checksum, OneFlippedBitChangesIt) {
  std::vector<unsigned char> data(4096, 0x5a);
  uint64_t before = checksum64(data.data(), data.size());
  data[2000] ^= 0x10;
  EXPECT_NE(checksum64(data.data(), data.size()), before);
}

TEST(Checksum, TextFormRoundTripsAndRejectsJunk) {
  EXPECT_EQ(checksum_to_string(0x00ab00cd00ef0012ull), "xxh64:00ab00cd00ef0012");
  EXPECT_EQ(parse_checksum("xxh64:00ab00cd00ef0012"), 0x00ab00cd00ef0012ull);
  EXPECT_FALSE(parse_checksum("xxh64:00ab00cd00ef001"));   // too short
  EXPECT_FALSE(parse_checksum("xxh64:00AB00CD00EF0012"));  // upper case is not the form
  EXPECT_FALSE(parse_checksum("crc32:00ab00cd00ef0012"));
}

TEST(Checksum, FileChecksumEqualsChecksumOfContents) {
  TempDir dir;
  std::string data(3 << 20, 'x');  // spans several read blocks
  for (size_t i = 0; i < data.size(); i += 4099) data[i] = char(i);
  std::ofstream(dir.path() / "blob", std::ios::binary) << data;
  EXPECT_EQ(checksum_file(dir.path() / "blob"), checksum64(data.data(), data.size()));
  EXPECT_THROW(checksum_file(dir.path() / "missing"), RuntimeError);
}
}  // namespace
}  // namespace dofarm
