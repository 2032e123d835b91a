#include "core/util/base64.h"

#include <gtest/gtest.h>

#include <random>
#include <string>

namespace surfacer {
namespace {

// RFC 4648's test vectors, and every length from 0 to 200 of random bytes back and forth.
TEST(Base64, EncodesTheRfcVectorsAndRoundTripsEveryLength) {
  const std::pair<const char*, const char*> vectors[] = {{"", ""},         {"f", "Zg=="},         {"fo", "Zm8="},
                                                         {"foo", "Zm9v"}, {"foob", "Zm9vYg=="}, {"fooba", "Zm9vYmE="},
                                                         {"foobar", "Zm9vYmFy"}};
  for (const auto& [plain, encoded] : vectors) {
    std::string out;
    append_base64(out, plain);
    EXPECT_EQ(out, encoded);
    EXPECT_EQ(decode_base64(encoded), std::string(plain));
    const std::string unpadded = std::string(encoded).substr(0, std::string(encoded).find('='));
    EXPECT_EQ(decode_base64(unpadded), std::string(plain)) << unpadded;
  }
  std::mt19937 random(7);
  for (int length = 0; length <= 200; ++length) {
    std::string bytes(length, '\0');
    for (char& c : bytes) c = static_cast<char>(random() & 255);
    std::string text;
    append_base64(text, bytes);
    EXPECT_EQ(text.size(), (bytes.size() + 2) / 3 * 4);
    EXPECT_EQ(decode_base64(text), bytes) << length;
  }
}

TEST(Base64, RefusesWhatNoEncoderWrites) {
  for (const char* bad : {"A", "Zm9vY", "Zm*v", "Zm9v\n", "Zg==Zg==", "Z=g=", "Zm9v Zm9v"}) {
    EXPECT_FALSE(decode_base64(bad).has_value()) << bad;
  }
}

}  // namespace
}  // namespace surfacer
