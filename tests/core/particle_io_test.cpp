#include "core/particles/particle_io.h"

#include <gtest/gtest.h>
#include <zlib.h>

#include <bit>
#include <cstring>
#include <filesystem>
#include <functional>
#include <random>

#include "core/util/errors.h"
#include "tests/support/files.h"

namespace surfacer {
namespace {

// --- Test data and writers (independent of the readers) ----------------------------------------------------------

ParticleFrame sample_frame(bool radii, std::size_t n = 57) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-3.0, 3.0), r(0.01, 0.2);
  ParticleFrame f;
  for (std::size_t i = 0; i < n; ++i) {
    // float-representable values so float32 formats round-trip exactly
    f.positions.emplace_back(static_cast<float>(u(rng)), static_cast<float>(u(rng)), static_cast<float>(u(rng) + 100));
    if (radii) f.radii.push_back(static_cast<float>(r(rng)));
  }
  return f;
}

void expect_same(const ParticleFrame& a, const ParticleFrame& b) {
  ASSERT_EQ(a.positions.size(), b.positions.size());
  for (std::size_t i = 0; i < a.positions.size(); ++i) EXPECT_EQ(a.positions[i], b.positions[i]) << i;
  EXPECT_EQ(a.radii, b.radii);
}

template <class T>
void put(std::string& out, T v, bool big_endian) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  if (big_endian != (std::endian::native == std::endian::big)) std::reverse(b, b + sizeof(T));
  out.append(b, sizeof(T));
}

std::string fmt(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

std::string write_xyz(const ParticleFrame& f, const std::string& sep) {
  std::string s = "# particles\n\n";
  for (std::size_t i = 0; i < f.positions.size(); ++i) {
    s += fmt(f.positions[i].x()) + sep + fmt(f.positions[i].y()) + sep + fmt(f.positions[i].z());
    if (!f.radii.empty()) s += sep + fmt(f.radii[i]);
    s += i % 5 == 0 ? "  # trailing comment\r\n" : "\n";
  }
  return s;
}

// PLY with a face element before the vertices (skipped) and an extra list + uchar property inside vertex.
std::string write_ply(const ParticleFrame& f, const std::string& format) {
  const bool ascii = format == "ascii";
  const bool big = format == "binary_big_endian";
  std::string s =
      "ply\nformat " + format + " 1.0\ncomment test\nelement face 2\nproperty list uchar int vertex_indices\n";
  s += "element vertex " + std::to_string(f.positions.size()) + "\n";
  s += "property double x\nproperty float y\nproperty uchar red\nproperty double z\n";
  s += "property list uchar short tags\n";
  if (!f.radii.empty()) s += "property float radius\n";
  s += "end_header\n";
  if (ascii) {
    s += "3 0 1 2\n4 0 1 2 3\n";
    for (std::size_t i = 0; i < f.positions.size(); ++i) {
      s += fmt(f.positions[i].x()) + " " + fmt(f.positions[i].y()) + " 200 " + fmt(f.positions[i].z()) + " 2 7 8";
      if (!f.radii.empty()) s += " " + fmt(f.radii[i]);
      s += "\n";
    }
    return s;
  }
  for (int face = 0; face < 2; ++face) {
    put<std::uint8_t>(s, static_cast<std::uint8_t>(3 + face), big);
    for (int k = 0; k < 3 + face; ++k) put<std::int32_t>(s, k, big);
  }
  for (std::size_t i = 0; i < f.positions.size(); ++i) {
    put<double>(s, f.positions[i].x(), big);
    put<float>(s, static_cast<float>(f.positions[i].y()), big);
    put<std::uint8_t>(s, 200, big);
    put<double>(s, f.positions[i].z(), big);
    put<std::uint8_t>(s, 1, big);
    put<std::int16_t>(s, 5, big);
    if (!f.radii.empty()) put<float>(s, static_cast<float>(f.radii[i]), big);
  }
  return s;
}

std::string write_vtk(const ParticleFrame& f, bool binary, const std::string& dataset, bool vtk51 = false) {
  const std::size_t n = f.positions.size();
  std::string s = "# vtk DataFile Version " + std::string(vtk51 ? "5.1" : "3.0") + "\nparticles\n" +
                  (binary ? "BINARY\n" : "ASCII\n") + "DATASET " + dataset + "\n";
  s += "FIELD FieldData 1\nTIME 1 1 double\n";
  if (binary) {
    put<double>(s, 0.5, true);
    s += "\n";
  } else {
    s += "0.5\n";
  }
  s += "POINTS " + std::to_string(n) + (binary ? " float\n" : " double\n");
  for (const Vec3& p : f.positions) {
    for (int a = 0; a < 3; ++a) {
      if (binary) {
        put<float>(s, static_cast<float>(p[a]), true);
      } else {
        s += fmt(p[a]) + (a == 2 ? "\n" : " ");
      }
    }
  }
  if (binary) s += "\n";
  const std::string cells = dataset == "POLYDATA" ? "VERTICES" : "CELLS";
  if (vtk51) {
    s += cells + " " + std::to_string(n + 1) + " " + std::to_string(n) + "\nOFFSETS vtktypeint64\n";
    for (std::size_t i = 0; i <= n; ++i) {
      if (binary) {
        put<std::int64_t>(s, static_cast<std::int64_t>(i), true);
      } else {
        s += std::to_string(i) + "\n";
      }
    }
    s += (binary ? "\n" : "") + std::string("CONNECTIVITY vtktypeint64\n");
    for (std::size_t i = 0; i < n; ++i) {
      if (binary) {
        put<std::int64_t>(s, static_cast<std::int64_t>(i), true);
      } else {
        s += std::to_string(i) + "\n";
      }
    }
  } else {
    s += cells + " " + std::to_string(n) + " " + std::to_string(2 * n) + "\n";
    for (std::size_t i = 0; i < n; ++i) {
      if (binary) {
        put<std::int32_t>(s, 1, true);
        put<std::int32_t>(s, static_cast<std::int32_t>(i), true);
      } else {
        s += "1 " + std::to_string(i) + "\n";
      }
    }
  }
  if (binary) s += "\n";
  if (dataset == "UNSTRUCTURED_GRID") {
    s += "CELL_TYPES " + std::to_string(n) + "\n";
    for (std::size_t i = 0; i < n; ++i) {
      if (binary) {
        put<std::int32_t>(s, 1, true);
      } else {
        s += "1\n";
      }
    }
    if (binary) s += "\n";
  }
  s += "POINT_DATA " + std::to_string(n) + "\nVECTORS velocity float\n";
  for (std::size_t i = 0; i < 3 * n; ++i) {
    if (binary) {
      put<float>(s, 1.5f, true);
    } else {
      s += "1.5\n";
    }
  }
  if (binary) s += "\n";
  if (!f.radii.empty()) {
    s += "SCALARS radius double 1\nLOOKUP_TABLE default\n";
    for (const double r : f.radii) {
      if (binary) {
        put<double>(s, r, true);
      } else {
        s += fmt(r) + "\n";
      }
    }
    if (binary) s += "\n";
  }
  s += "METADATA\nINFORMATION 0\n\n";
  return s;
}

std::string base64(const std::string& bytes) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  for (std::size_t i = 0; i < bytes.size(); i += 3) {
    const unsigned b0 = static_cast<unsigned char>(bytes[i]);
    const unsigned b1 = i + 1 < bytes.size() ? static_cast<unsigned char>(bytes[i + 1]) : 0;
    const unsigned b2 = i + 2 < bytes.size() ? static_cast<unsigned char>(bytes[i + 2]) : 0;
    const unsigned v = b0 << 16 | b1 << 8 | b2;
    out += k[v >> 18];
    out += k[(v >> 12) & 63];
    out += i + 1 < bytes.size() ? k[(v >> 6) & 63] : '=';
    out += i + 2 < bytes.size() ? k[v & 63] : '=';
  }
  return out;
}

struct VtuStyle {
  std::string format = "ascii";   // ascii | binary | appended
  std::string header = "UInt32";  // UInt32 | UInt64
  bool big_endian = false;
  bool separate_header = true;  // header and data base64-encoded separately (as VTK does)
  bool float64 = false;
  int pieces = 1;
  std::string compressor;        // "" or vtkZLibDataCompressor (or any name, written as is)
  std::string encoding = "raw";  // of <AppendedData>: raw | base64
  std::size_t block_bytes = 64;  // uncompressed bytes per zlib block (small: several blocks per array)
};

void put_word(std::string& out, std::uint64_t v, const VtuStyle& st) {
  if (st.header == "UInt64") {
    put<std::uint64_t>(out, v, st.big_endian);
  } else {
    put<std::uint32_t>(out, static_cast<std::uint32_t>(v), st.big_endian);
  }
}

std::string zlib(std::string_view raw) {
  uLongf size = compressBound(static_cast<uLong>(raw.size()));
  std::string out(size, '\0');
  EXPECT_EQ(compress(reinterpret_cast<Bytef*>(out.data()), &size, reinterpret_cast<const Bytef*>(raw.data()),
                     static_cast<uLong>(raw.size())),
            Z_OK);
  out.resize(size);
  return out;
}

// A binary array's header and data: a byte count and the values, or VTK's zlib layout (blocks, block size, partial
// last block size or 0, each block's compressed size; then the blocks).
std::pair<std::string, std::string> vtu_payload(const std::string& raw, const VtuStyle& st) {
  std::string header, data;
  if (st.compressor != "vtkZLibDataCompressor") {
    put_word(header, raw.size(), st);
    return {header, raw};
  }
  const std::size_t blocks = (raw.size() + st.block_bytes - 1) / st.block_bytes;
  put_word(header, blocks, st);
  put_word(header, st.block_bytes, st);
  put_word(header, raw.size() % st.block_bytes, st);
  for (std::size_t b = 0; b < blocks; ++b) {
    const std::string z = zlib(std::string_view(raw).substr(b * st.block_bytes, st.block_bytes));
    put_word(header, z.size(), st);
    data += z;
  }
  return {header, data};
}

std::string vtu_array(const std::vector<double>& values, const std::string& name, int components, const VtuStyle& st,
                      std::string* appended = nullptr) {
  const std::string type = st.float64 ? "Float64" : "Float32";
  std::string s = "<DataArray type=\"" + type + "\" " + (name.empty() ? "" : "Name=\"" + name + "\" ") +
                  "NumberOfComponents=\"" + std::to_string(components) + "\" format=\"" + st.format + "\"";
  if (st.format == "ascii") {
    s += ">\n";
    for (const double v : values) s += fmt(v) + " ";
    return s + "\n</DataArray>\n";
  }
  std::string raw;
  for (const double v : values) {
    if (st.float64) {
      put<double>(raw, v, st.big_endian);
    } else {
      put<float>(raw, static_cast<float>(v), st.big_endian);
    }
  }
  const auto [header, data] = vtu_payload(raw, st);
  if (st.format == "appended") {
    s += " offset=\"" + std::to_string(appended->size()) + "\"/>\n";
    *appended += st.encoding != "base64" ? header + data
                 : st.separate_header    ? base64(header) + base64(data)
                                         : base64(header + data);
    return s;
  }
  s += ">\n";
  s += st.separate_header ? base64(header) + base64(data) : base64(header + data);
  return s + "\n</DataArray>\n";
}

std::string write_vtu(const ParticleFrame& f, const VtuStyle& st) {
  std::string s =
      "<?xml version=\"1.0\"?>\n<!-- written by the test -->\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" "
      "byte_order=\"" +
      std::string(st.big_endian ? "BigEndian" : "LittleEndian") + "\" header_type=\"" + st.header + "\"" +
      (st.compressor.empty() ? "" : " compressor=\"" + st.compressor + "\"") + ">\n<UnstructuredGrid>\n";
  const std::size_t n = f.positions.size();
  std::string appended;
  for (int piece = 0; piece < st.pieces; ++piece) {
    const std::size_t begin = n * piece / st.pieces, end = n * (piece + 1) / st.pieces;
    s += "<Piece NumberOfPoints=\"" + std::to_string(end - begin) +
         "\" NumberOfCells=\"0\">\n<PointData Scalars=\"radius\">\n";
    s += vtu_array(std::vector<double>(end - begin, 2.0), "density", 1, st, &appended);
    if (!f.radii.empty()) {
      s += vtu_array(std::vector<double>(f.radii.begin() + begin, f.radii.begin() + end), "radius", 1, st, &appended);
    }
    s += "</PointData>\n<Points>\n";
    std::vector<double> xyz;
    for (std::size_t i = begin; i < end; ++i)
      xyz.insert(xyz.end(), {f.positions[i].x(), f.positions[i].y(), f.positions[i].z()});
    s += vtu_array(xyz, "Points", 3, st, &appended);
    s += "</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" "
         "format=\"ascii\"></DataArray>\n</Cells>\n</Piece>\n";
  }
  s += "</UnstructuredGrid>\n";
  if (st.format == "appended")
    s += "<AppendedData encoding=\"" + st.encoding + "\">\n   _" + appended + "\n</AppendedData>\n";
  return s + "</VTKFile>\n";
}

std::string write_bin(const ParticleFrame& f) {
  std::string s;
  for (const Vec3& p : f.positions) {
    for (int a = 0; a < 3; ++a) put<float>(s, static_cast<float>(p[a]), false);
  }
  return s;
}

// Classic BGEO as Partio writes it: header, point attribute dictionary (here an indexed string, a vector and
// pscale), then x y z w and the attribute words per point, then an empty primitive section.
std::string write_bgeo(const ParticleFrame& f) {
  std::string s = "Bgeo";
  s += 'V';
  const bool radii = !f.radii.empty();
  const std::int32_t header[] = {5, static_cast<std::int32_t>(f.positions.size()), 0, 0, 0, radii ? 3 : 2, 0, 0, 0};
  for (const std::int32_t v : header) put<std::int32_t>(s, v, true);
  auto name = [&](const std::string& n) {
    put<std::uint16_t>(s, static_cast<std::uint16_t>(n.size()), true);
    s += n;
  };
  name("kind");
  put<std::uint16_t>(s, 1, true);
  put<std::int32_t>(s, 4, true);  // indexed string
  put<std::int32_t>(s, 2, true);
  name("water");
  name("foam");
  name("v");
  put<std::uint16_t>(s, 3, true);
  put<std::int32_t>(s, 5, true);  // vector
  for (int k = 0; k < 3; ++k) put<float>(s, 0.0f, true);
  if (radii) {
    name("pscale");
    put<std::uint16_t>(s, 1, true);
    put<std::int32_t>(s, 0, true);  // float
    put<float>(s, 1.0f, true);
  }
  for (std::size_t i = 0; i < f.positions.size(); ++i) {
    for (int a = 0; a < 3; ++a) put<float>(s, static_cast<float>(f.positions[i][a]), true);
    put<float>(s, 1.0f, true);
    put<std::int32_t>(s, static_cast<std::int32_t>(i % 2), true);
    for (int k = 0; k < 3; ++k) put<float>(s, 0.25f, true);
    if (radii) put<float>(s, static_cast<float>(f.radii[i]), true);
  }
  s += "beginExtra";
  return s;
}

using testing::gzip;

class TempDir {
 public:
  TempDir() : path_(testing::fresh_temp_dir("particle_io")) {}
  ~TempDir() { std::filesystem::remove_all(path_); }
  std::filesystem::path write(const std::string& name, const std::string& bytes) const {
    const std::filesystem::path p = path_ / name;
    testing::write_file(p, bytes);
    return p;
  }

 private:
  std::filesystem::path path_;
};

// Expects InvalidInput("file") whose message starts with `name: ` and contains every fragment.
void expect_error(std::string_view bytes, ParticleFormat format, const std::string& name,
                  std::initializer_list<std::string> fragments) {
  try {
    const ParticleFrame f = parse_particles(bytes, format, name);
    ADD_FAILURE() << "parsed without error: " << f.positions.size() << " particles";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
    EXPECT_EQ(e.field(), "file");
    const std::string what = e.what();
    EXPECT_EQ(what.rfind(name + ": ", 0), 0u) << what;
    for (const std::string& f : fragments) EXPECT_NE(what.find(f), std::string::npos) << what << " lacks " << f;
  }
}

// Every prefix and a few hundred random corruptions must parse or fail with InvalidInput, never crash or hang.
void fuzz(const std::string& good, ParticleFormat format) {
  auto attempt = [&](const std::string& bytes) {
    try {
      (void)parse_particles(bytes, format, "fuzz");
    } catch (const Error& e) {
      EXPECT_TRUE(e.kind() == ErrorKind::kInvalidInput || e.kind() == ErrorKind::kResourceLimit) << e.what();
    }
  };
  const std::size_t step = std::max<std::size_t>(1, good.size() / 400);
  for (std::size_t len = 0; len < good.size(); len += step) attempt(good.substr(0, len));
  std::mt19937 rng(11);
  for (int trial = 0; trial < 300; ++trial) {
    std::string bad = good;
    const int flips = 1 + static_cast<int>(rng() % 8);
    for (int k = 0; k < flips; ++k) bad[rng() % bad.size()] = static_cast<char>(rng());
    attempt(bad);
  }
}

// --- Round trips ---------------------------------------------------------------------------------------------------

TEST(ParticleIo, XyzRoundTripWhitespaceCommasAndRadius) {
  for (const bool radii : {false, true}) {
    const ParticleFrame f = sample_frame(radii);
    expect_same(parse_particles(write_xyz(f, " "), ParticleFormat::kXyz, "a.xyz"), f);
    expect_same(parse_particles(write_xyz(f, ", "), ParticleFormat::kXyz, "a.csv"), f);
    expect_same(parse_particles(write_xyz(f, "\t"), ParticleFormat::kXyz, "a.txt"), f);
  }
}

TEST(ParticleIo, XyzHeaderSelectsColumnsByName) {
  const std::string text = "id,Z,y,x,pscale,vx\n1,3,2,1,0.5,9\n2,6,5,4,0.25,9\n";
  const ParticleFrame f = parse_particles(text, ParticleFormat::kXyz, "h.csv");
  ASSERT_EQ(f.positions.size(), 2u);
  EXPECT_EQ(f.positions[0], Vec3(1, 2, 3));
  EXPECT_EQ(f.positions[1], Vec3(4, 5, 6));
  EXPECT_EQ(f.radii, (std::vector<double>{0.5, 0.25}));
}

TEST(ParticleIo, PlyRoundTripAllEncodings) {
  for (const std::string format : {"ascii", "binary_little_endian", "binary_big_endian"}) {
    for (const bool radii : {false, true}) {
      const ParticleFrame f = sample_frame(radii);
      SCOPED_TRACE(format);
      expect_same(parse_particles(write_ply(f, format), ParticleFormat::kPly, "p.ply"), f);
    }
  }
}

TEST(ParticleIo, VtkLegacyRoundTrip) {
  for (const bool binary : {false, true}) {
    for (const std::string dataset : {"POLYDATA", "UNSTRUCTURED_GRID"}) {
      for (const bool vtk51 : {false, true}) {
        for (const bool radii : {false, true}) {
          SCOPED_TRACE(dataset + (binary ? " binary" : " ascii") + (vtk51 ? " 5.1" : " 3.0"));
          const ParticleFrame f = sample_frame(radii);
          expect_same(parse_particles(write_vtk(f, binary, dataset, vtk51), ParticleFormat::kVtk, "p.vtk"), f);
        }
      }
    }
  }
}

TEST(ParticleIo, VtuRoundTripAsciiAndBase64) {
  std::vector<VtuStyle> styles(7);
  styles[1].format = "binary";
  styles[2] = styles[1];
  styles[2].header = "UInt64";
  styles[3] = styles[1];
  styles[3].separate_header = false;
  styles[4] = styles[1];
  styles[4].big_endian = true;
  styles[4].float64 = true;
  styles[5] = styles[2];
  styles[5].pieces = 3;
  styles[6].pieces = 2;
  for (std::size_t k = 0; k < styles.size(); ++k) {
    for (const bool radii : {false, true}) {
      SCOPED_TRACE(k);
      const ParticleFrame f = sample_frame(radii, 58);
      expect_same(parse_particles(write_vtu(f, styles[k]), ParticleFormat::kVtu, "p.vtu"), f);
    }
  }
}

// Found by fuzz/fuzz_particles (fuzz/corpus/particles/crash-vtu-two-radius-arrays): a piece with two PointData
// arrays named radius/pscale had both appended to the radii (2 N radii for N particles).
TEST(ParticleIo, VtuTakesThePiecesFirstRadiusArray) {
  const ParticleFrame f = sample_frame(true, 12);
  VtuStyle st;
  std::vector<double> xyz;
  for (const Vec3& p : f.positions) xyz.insert(xyz.end(), {p.x(), p.y(), p.z()});
  std::string s =
      "<VTKFile type=\"UnstructuredGrid\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"12\">\n"
      "<PointData>\n";
  s += vtu_array(f.radii, "radius", 1, st);
  s += vtu_array(std::vector<double>(12, 9.0), "pscale", 1, st);
  s += "</PointData>\n<Points>\n" + vtu_array(xyz, "Points", 3, st) + "</Points>\n</Piece>\n";
  s += "</UnstructuredGrid>\n</VTKFile>\n";
  expect_same(parse_particles(s, ParticleFormat::kVtu, "two.vtu"), f);
}

// Found by fuzz/fuzz_particles (fuzz/corpus/particles/crash-vtu-nested-piece): a <Piece> opened inside another
// restarted the piece's counts, so the outer piece's radii were kept on top of the inner one's (2 radii, 1 point),
// and a file ending with the outer piece still open was accepted.
TEST(ParticleIo, VtuRefusesAPieceInsideAPiece) {
  VtuStyle st;
  const std::string radius = vtu_array({0.5}, "radius", 1, st);
  const std::string s =
      "<VTKFile type=\"UnstructuredGrid\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"1\">\n"
      "<PointData>\n" +
      radius + "</PointData>\n<Piece NumberOfPoints=\"1\">\n<PointData>\n" + radius + "</PointData>\n<Points>\n" +
      vtu_array({1, 2, 3}, "Points", 3, st) + "</Points>\n</Piece>\n";
  expect_error(s, ParticleFormat::kVtu, "nested.vtu", {"line 9", "<Piece> inside another <Piece>"});
}

TEST(ParticleIo, BinRoundTrip) {
  const ParticleFrame f = sample_frame(false);
  expect_same(parse_particles(write_bin(f), ParticleFormat::kBin, "p.bin"), f);
  EXPECT_TRUE(parse_particles("", ParticleFormat::kBin, "e.bin").positions.empty());
}

TEST(ParticleIo, BgeoRoundTripPlainAndGzip) {
  for (const bool radii : {false, true}) {
    const ParticleFrame f = sample_frame(radii);
    expect_same(parse_particles(write_bgeo(f), ParticleFormat::kBgeo, "f.bgeo"), f);
    expect_same(parse_particles(gzip(write_bgeo(f)), ParticleFormat::kBgeo, "f.bgeo.gz"), f);
  }
}

TEST(ParticleIo, ReadFilesByExtensionIncludingGzip) {
  const TempDir dir;
  const ParticleFrame f = sample_frame(true);
  expect_same(read_particles(dir.write("a.xyz", write_xyz(f, " "))), f);
  expect_same(read_particles(dir.write("a.PLY", write_ply(f, "binary_little_endian"))), f);
  expect_same(read_particles(dir.write("a.vtk", write_vtk(f, true, "POLYDATA"))), f);
  expect_same(read_particles(dir.write("a.vtu", write_vtu(f, VtuStyle{}))), f);
  expect_same(read_particles(dir.write("a.bgeo", write_bgeo(f))), f);
  expect_same(read_particles(dir.write("a.bgeo.gz", gzip(write_bgeo(f)))), f);
  expect_same(read_particles(dir.write("a.bhclassic", gzip(write_bgeo(f)))), f);
  expect_same(read_particles(dir.write("a.ply.gz", gzip(write_ply(f, "ascii")))), f);
  const ParticleFrame g = sample_frame(false);
  expect_same(read_particles(dir.write("a.bin", write_bin(g))), g);
  try {
    read_particles(dir.write("a.obj", "v 1 2 3\n"));
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("a.obj"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find(".bgeo"), std::string::npos);
  }
  try {
    read_particles(dir.write("x", "").parent_path() / "missing.xyz");
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("missing.xyz: cannot open"), std::string::npos) << e.what();
  }
}

// A ResourceLimit("file") whose message holds every one of `parts`.
void expect_limit(const std::function<void()>& read, const std::vector<std::string>& parts) {
  try {
    read();
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit) << e.what();
    EXPECT_EQ(e.field(), "file");
    for (const auto& part : parts) EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
  }
}

TEST(ParticleIo, LimitsStopBombsAndLargeFilesEarly) {
  const TempDir dir;
  // 64 MiB of zeros in ~64 KiB of gzip, twice over as two members: stopped at the limit, whatever follows.
  const std::string member = gzip(std::string(std::size_t{64} << 20, '\0'));
  ParticleReadLimits limits;
  limits.max_bytes = 12000;
  expect_limit([&] { parse_particles(member + member, ParticleFormat::kBin, "bomb.bin.gz", limits); },
               {"bomb.bin.gz: its gzip data inflates to more than 12000 bytes"});
  expect_limit([&] { read_particles(dir.write("bomb.xyz.gz", member + member), limits); }, {"bomb.xyz.gz"});
  // Members within the limit are one stream.
  const ParticleFrame f = sample_frame(false, 10);
  expect_same(parse_particles(gzip(write_bin(f)) + gzip(""), ParticleFormat::kBin, "two.bin.gz", limits), f);
  // Plain files: by their size, before reading them.
  limits.max_bytes = 100;
  expect_limit([&] { read_particles(dir.write("big.xyz", std::string(101, ' ')), limits); },
               {"big.xyz: it holds more than 100 bytes"});
  // Particles: a raw file by its size, before parsing; others once parsed.
  limits = {};
  limits.max_particles = 9;
  expect_limit([&] { parse_particles(write_bin(f), ParticleFormat::kBin, "ten.bin", limits); },
               {"ten.bin: 10 particles, more than 9"});
  expect_limit([&] { parse_particles(write_xyz(f, " "), ParticleFormat::kXyz, "ten.xyz", limits); },
               {"ten.xyz: 10 particles, more than 9"});
  limits.max_particles = 10;
  expect_same(parse_particles(write_xyz(f, " "), ParticleFormat::kXyz, "ten.xyz", limits), f);
}

// --- Errors name the file and the line or byte -------------------------------------------------------------------

TEST(ParticleIo, TextErrorsNameTheLine) {
  expect_error("1 2 3\n4 5 6\n7 x 9\n", ParticleFormat::kXyz, "bad.xyz", {"line 3", "'x' is not a number"});
  expect_error("1 2 3\n4 5 6 7\n", ParticleFormat::kXyz, "bad.xyz", {"line 2", "expected 3 values"});
  expect_error("# c\n1 2\n", ParticleFormat::kXyz, "bad.xyz", {"line 2", "expected 3 or 4 values"});
  expect_error("1 2 3\n1 nan 3\n", ParticleFormat::kXyz, "bad.xyz", {"line 2", "non-finite"});
  expect_error("a,b,c\n1,2,3\n", ParticleFormat::kXyz, "bad.csv", {"line 1", "x, y and z"});
  expect_error(
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
      "end_header\n1 2 3\n4 5\n",
      ParticleFormat::kPly, "bad.ply", {"line 9", "expected 3 numbers for vertex 1"});
  expect_error("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
               ParticleFormat::kPly, "bad.ply", {"lacks an x, y or z"});
  expect_error("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nwhat\n", ParticleFormat::kPly, "bad.ply",
               {"line 5", "unknown header keyword"});
  expect_error("# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 2 float\n1 2 3\n4 5 q\n",
               ParticleFormat::kVtk, "bad.vtk", {"line 7", "'q' is not a number"});
  expect_error("# vtk DataFile Version 3.0\nt\nASCII\nDATASET STRUCTURED_POINTS\n", ParticleFormat::kVtk, "bad.vtk",
               {"line 4", "not supported"});
  expect_error(
      "<VTKFile type=\"UnstructuredGrid\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"2\">\n<Points>\n"
      "<DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">\n1 2 3 4 5\n</DataArray>\n",
      ParticleFormat::kVtu, "bad.vtu", {"line 6", "has 5 values, expected 6"});
}

TEST(ParticleIo, BinaryErrorsNameTheByteOffset) {
  const ParticleFrame f = sample_frame(true, 10);
  // BGEO cut inside point 3: header 41 bytes + dictionary, then 9 words (36 bytes) per point.
  const std::string bgeo = write_bgeo(f);
  const std::size_t dictionary_end = bgeo.size() - 10 * 36 - std::string("beginExtra").size();
  expect_error(std::string_view(bgeo).substr(0, dictionary_end + 3 * 36 + 5), ParticleFormat::kBgeo, "cut.bgeo",
               {"byte " + std::to_string(dictionary_end + 3 * 36), "truncated point 3 of 10", "5 left"});
  expect_error(std::string_view(bgeo).substr(0, 20), ParticleFormat::kBgeo, "cut.bgeo",
               {"byte 17", "truncated header"});
  expect_error(std::string("\x7fNSJ", 4) + std::string(60, '\0'), ParticleFormat::kBgeo, "new.bgeo",
               {"byte 0", "classic"});
  // The same cut inside gzip data: offsets are into the inflated bytes.
  std::string cut_gz = gzip(bgeo.substr(0, dictionary_end + 3 * 36 + 5));
  expect_error(cut_gz, ParticleFormat::kBgeo, "cut.bgeo.gz", {"byte " + std::to_string(dictionary_end + 3 * 36)});
  // A gzip stream cut short.
  const std::string gz = gzip(bgeo);
  expect_error(std::string_view(gz).substr(0, gz.size() / 2), ParticleFormat::kBgeo, "half.bgeo.gz", {"gzip"});
  // Raw float triples.
  expect_error(std::string(25, '\0'), ParticleFormat::kBin, "odd.bin", {"byte 24", "1 trailing bytes"});
  // Binary PLY cut inside vertex 4 of 10 (after 2 faces of 13 and 17 bytes; 24 or 28 bytes per vertex): the error
  // names the first byte of the vertex that does not fit.
  const std::string ply = write_ply(f, "binary_little_endian");
  const std::size_t data = ply.find("end_header\n") + 11;
  expect_error(std::string_view(ply).substr(0, data + 30 + 4 * 28 + 9), ParticleFormat::kPly, "cut.ply",
               {"byte " + std::to_string(data + 30 + 4 * 28), "unexpected end of file in vertex 4 of 10"});
  // Binary VTK cut inside the points.
  const std::string vtk = write_vtk(f, true, "POLYDATA");
  const std::size_t points = vtk.find(" float\n") + 7;
  expect_error(std::string_view(vtk).substr(0, points + 50), ParticleFormat::kVtk, "cut.vtk",
               {"byte " + std::to_string(points), "truncated POINTS", "50 left"});
}

TEST(ParticleIo, VtuRoundTripAppendedAndCompressed) {
  // VTK's default (appended raw, zlib), meshio's (inline binary, zlib), and the other combinations.
  std::vector<VtuStyle> styles;
  for (const std::string format : {"appended", "binary"}) {
    for (const std::string compressor : {"", "vtkZLibDataCompressor"}) {
      for (const std::string encoding : {"raw", "base64"}) {
        if (format == "binary" && encoding == "base64") continue;  // (inline data is always base64)
        VtuStyle st;
        st.format = format;
        st.compressor = compressor;
        st.encoding = encoding;
        styles.push_back(st);
        st.header = "UInt64";
        st.big_endian = true;
        st.float64 = true;
        st.pieces = 3;
        st.block_bytes = 1 << 15;  // one block per array, with a partial last block
        styles.push_back(st);
      }
    }
  }
  for (const VtuStyle& st : styles) {
    for (const bool radii : {false, true}) {
      for (const std::size_t n : {std::size_t{0}, std::size_t{1}, std::size_t{58}}) {
        SCOPED_TRACE(st.format + " " + st.compressor + " " + st.encoding + " " + st.header + " pieces " +
                     std::to_string(st.pieces) + " n " + std::to_string(n) + (radii ? " radii" : ""));
        const ParticleFrame f = sample_frame(radii, n);
        expect_same(parse_particles(write_vtu(f, st), ParticleFormat::kVtu, "p.vtu"), f);
      }
    }
  }
  // A whole block (64 bytes = 16 floats, and 48 floats of points: 3 full blocks, last size 0).
  VtuStyle st;
  st.format = "binary";
  st.compressor = "vtkZLibDataCompressor";
  const ParticleFrame f = sample_frame(false, 16);
  expect_same(parse_particles(write_vtu(f, st), ParticleFormat::kVtu, "p.vtu"), f);
  TempDir dir;
  expect_same(read_particles(dir.write("on_disk.vtu", write_vtu(f, st))), f);
}

TEST(ParticleIo, VtuLayoutsOfVtksOwnWriters) {
  EXPECT_EQ(particle_format_from_path("a/B.vtp"), ParticleFormat::kVtu);
  const ParticleFrame f = sample_frame(true, 58);
  // Appended base64: VTK 9 encodes an uncompressed array's byte count and values as one base64 unit, a compressed
  // array's block header and blocks as two; both layouts read either way.
  for (const std::string compressor : {"", "vtkZLibDataCompressor"}) {
    for (const bool separate : {false, true}) {
      SCOPED_TRACE(compressor + (separate ? " separate" : " one unit"));
      VtuStyle st;
      st.format = "appended";
      st.encoding = "base64";
      st.compressor = compressor;
      st.separate_header = separate;
      expect_same(parse_particles(write_vtu(f, st), ParticleFormat::kVtu, "p.vtu"), f);
    }
  }
  // VTK writes an <InformationKey> after the values of every Points array.
  for (const std::string format : {"ascii", "binary"}) {
    SCOPED_TRACE(format);
    VtuStyle st;
    st.format = format;
    std::string vtu = write_vtu(f, st);
    vtu.insert(vtu.find("</DataArray>", vtu.find("<Points>")),
               "<InformationKey name=\"L2_NORM_RANGE\" location=\"vtkDataArray\" length=\"2\">\n"
               "<Value index=\"0\">\n0.1\n</Value>\n<Value index=\"1\">\n1.7\n</Value>\n</InformationKey>\n");
    expect_same(parse_particles(vtu, ParticleFormat::kVtu, "p.vtu"), f);
  }
}

TEST(ParticleIo, VtuVariantsWeDoNotReadSayWhy) {
  const ParticleFrame f = sample_frame(false, 4);
  VtuStyle unknown;  // (zlib, LZ4 and LZMA are read: tests/core/vtk_writer_files_test.py)
  unknown.format = "binary";
  unknown.compressor = "vtkBrotliDataCompressor";
  expect_error(write_vtu(f, unknown), ParticleFormat::kVtu, "c.vtu", {"line 3", "vtkBrotliDataCompressor", "zlib"});
  VtuStyle binary;
  binary.format = "binary";
  std::string bad = write_vtu(f, binary);
  bad.replace(bad.find("AAAA", bad.find("<Points>")), 1, "!");
  expect_error(bad, ParticleFormat::kVtu, "b.vtu", {"invalid base64"});
  VtuStyle appended;
  appended.format = "appended";
  std::string no_data = write_vtu(f, appended);
  no_data.erase(no_data.find("<AppendedData"));
  expect_error(no_data + "</VTKFile>\n", ParticleFormat::kVtu, "a.vtu", {"no <AppendedData>"});
  // (the first array, density, is not read: the Points' offset is the one that matters)
  auto points_offset = [](const std::string& vtu) { return vtu.find("offset=\"", vtu.find("<Points>")) + 8; };
  std::string far = write_vtu(f, appended);
  far.replace(points_offset(far), far.find('"', points_offset(far)) - points_offset(far), "99999");
  expect_error(far, ParticleFormat::kVtu, "a.vtu", {"offset 99999", "past the end"});
  VtuStyle zlib_style = appended;
  zlib_style.compressor = "vtkZLibDataCompressor";
  std::string corrupt = write_vtu(f, zlib_style);
  const std::size_t data = corrupt.find('_', corrupt.find("<AppendedData")) + 1;
  const std::size_t at = points_offset(corrupt);
  const std::size_t offset = std::stoul(corrupt.substr(at, corrupt.find('"', at) - at));
  corrupt[data + offset + 4 * 4 + 3] ^= 0x55;  // inside the Points' first zlib block, past its 2-byte header
  expect_error(corrupt, ParticleFormat::kVtu, "z.vtu", {"does not inflate"});
}

// A compressed inline DataArray whose header is `words` (UInt64) followed by `blocks` of data.
std::string vtu_with_compressed_points(std::uint64_t points, const std::vector<std::uint64_t>& words,
                                       const std::string& blocks) {
  std::string header;
  for (const std::uint64_t w : words) put<std::uint64_t>(header, w, false);
  return "<VTKFile type=\"UnstructuredGrid\" header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\">\n"
         "<UnstructuredGrid><Piece NumberOfPoints=\"" +
         std::to_string(points) +
         "\"><Points>\n<DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"binary\">" + base64(header) +
         base64(blocks) + "</DataArray></Points></Piece></UnstructuredGrid></VTKFile>\n";
}

TEST(ParticleIo, VtuHostileCompressedSizesAreRefusedBeforeAllocating) {
  // 4e9 points declared, one block "inflating" 48 GB from 16 bytes: more than zlib can produce.
  const std::uint64_t points = 4000000000;
  expect_error(vtu_with_compressed_points(points, {1, points * 12, 0, 16}, std::string(16, 'x')), ParticleFormat::kVtu,
               "lie.vtu", {"more than zlib can produce"});
  // Block sizes that multiply past 2^64 (and would wrap to the expected size).
  expect_error(vtu_with_compressed_points(1, {3, std::uint64_t{1} << 63, 12, 1, 1, 1}, "abc"), ParticleFormat::kVtu,
               "wrap.vtu", {"expected 12 bytes"});
  // Billions of blocks declared in a few bytes.
  expect_error(vtu_with_compressed_points(1, {std::uint64_t{1} << 40, 12, 0}, ""), ParticleFormat::kVtu, "blocks.vtu",
               {"too short"});
  // Real zlib data of 8 MB of zeros (a few KB): refused past the byte limit as a ResourceLimit, naming the file.
  const std::uint64_t n = (8u << 20) / 12;
  const std::string zeros = zlib(std::string(static_cast<std::size_t>(n * 12), '\0'));
  const std::string bomb = vtu_with_compressed_points(n, {1, n * 12, 0, zeros.size()}, zeros);
  ParticleReadLimits limits;
  limits.max_bytes = 1 << 20;
  try {
    parse_particles(bomb, ParticleFormat::kVtu, "bomb.vtu", limits);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit) << e.what();
    EXPECT_NE(std::string(e.what()).find("bomb.vtu"), std::string::npos) << e.what();
  }
  EXPECT_EQ(parse_particles(bomb, ParticleFormat::kVtu, "bomb.vtu").positions.size(), n);  // within the default
}

TEST(ParticleIo, JsonRoundTripAndErrors) {
  for (const std::size_t n : {std::size_t{0}, std::size_t{1}, std::size_t{57}}) {
    const ParticleFrame f = sample_frame(false, n);
    std::string json = "[";
    for (std::size_t i = 0; i < n; ++i) {
      json += std::string(i == 0 ? "" : ",") + (i % 7 == 0 ? "\n  " : " ") + "[" + fmt(f.positions[i].x()) + ", " +
              fmt(f.positions[i].y()) + ",\t" + fmt(f.positions[i].z()) + "]";
    }
    json += "]\n";
    expect_same(parse_particles(json, ParticleFormat::kJson, "p.json"), f);
    TempDir dir;
    expect_same(read_particles(dir.write("p.json", json)), f);
    expect_same(read_particles(dir.write("p.json.gz", gzip(json))), f);
  }
  EXPECT_EQ(particle_format_from_path("a/B.JSON"), ParticleFormat::kJson);
  expect_error("[[1, 2, 3],\n [4, 5]]", ParticleFormat::kJson, "p.json", {"line 2", "particle 1"});
  expect_error("[[1, 2, 3, 4]]", ParticleFormat::kJson, "p.json", {"line 1", "']' after the 3 coordinates"});
  expect_error("[[1, 2, x]]", ParticleFormat::kJson, "p.json", {"expected a number", "particle 0"});
  expect_error("[[1, 2, 3]] extra", ParticleFormat::kJson, "p.json", {"after the closing"});
  expect_error("{\"points\": []}", ParticleFormat::kJson, "p.json", {"'[' to open the list"});
  expect_error("[[1, 2, 3],", ParticleFormat::kJson, "p.json", {"found the end"});
  expect_error("[[1e999, 2, 3]]", ParticleFormat::kJson, "p.json", {"expected a number", "1e999"});
}

TEST(ParticleIo, BinaryXyzPointsToBin) {
  const ParticleFrame f = sample_frame(false, 10);
  expect_error(write_bin(f), ParticleFormat::kXyz, "splash.xyz", {"byte ", "rename it to .bin"});
  TempDir dir;
  const std::filesystem::path xyz = dir.write("splash.xyz", write_bin(f));
  try {
    read_particles(xyz);
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(".bin"), std::string::npos) << e.what();
  }
  // The same bytes as .bin, and text .xyz (with a UTF-8 comment) as before.
  expect_same(read_particles(dir.write("splash.bin", write_bin(f))), f);
  expect_same(parse_particles("# caf\xc3\xa9\n" + write_xyz(f, " "), ParticleFormat::kXyz, "a.xyz"), f);
}

TEST(ParticleIo, TruncatedAndCorruptFilesNeverCrash) {
  const ParticleFrame f = sample_frame(true, 20);
  fuzz(write_xyz(f, ","), ParticleFormat::kXyz);
  fuzz(write_ply(f, "ascii"), ParticleFormat::kPly);
  fuzz(write_ply(f, "binary_big_endian"), ParticleFormat::kPly);
  fuzz(write_vtk(f, false, "UNSTRUCTURED_GRID"), ParticleFormat::kVtk);
  fuzz(write_vtk(f, true, "POLYDATA", true), ParticleFormat::kVtk);
  VtuStyle binary;
  binary.format = "binary";
  fuzz(write_vtu(f, binary), ParticleFormat::kVtu);
  fuzz(write_vtu(f, VtuStyle{}), ParticleFormat::kVtu);
  VtuStyle compressed = binary;
  compressed.compressor = "vtkZLibDataCompressor";
  fuzz(write_vtu(f, compressed), ParticleFormat::kVtu);
  compressed.format = "appended";
  fuzz(write_vtu(f, compressed), ParticleFormat::kVtu);
  compressed.encoding = "base64";
  fuzz(write_vtu(f, compressed), ParticleFormat::kVtu);
  fuzz("[[1, 2, 3], [4.5, -6e-3, 7]]", ParticleFormat::kJson);
  fuzz(write_bin(f), ParticleFormat::kBin);
  fuzz(write_bgeo(f), ParticleFormat::kBgeo);
  fuzz(gzip(write_bgeo(f)), ParticleFormat::kBgeo);
}

TEST(ParticleIo, HostileCountsDoNotAllocate) {
  // A header claiming 2^31 - 1 points with no data fails fast instead of reserving gigabytes.
  std::string bgeo = "BgeoV";
  for (const std::int32_t v : {5, 0x7fffffff, 0, 0, 0, 0, 0, 0, 0}) put<std::int32_t>(bgeo, v, true);
  expect_error(bgeo, ParticleFormat::kBgeo, "huge.bgeo", {"truncated point 0 of 2147483647"});
  expect_error(
      "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000000\nproperty float x\nproperty float y\n"
      "property float z\nend_header\n",
      ParticleFormat::kPly, "huge.ply", {"unexpected end of file in vertex 0 of 4000000000000"});
  expect_error("# vtk DataFile Version 3.0\nt\nBINARY\nDATASET POLYDATA\nPOINTS 999999999999 float\n",
               ParticleFormat::kVtk, "huge.vtk", {"truncated POINTS"});
}

// --- Sequences -----------------------------------------------------------------------------------------------------

TEST(ParticleIo, ExpandSequence) {
  using P = std::filesystem::path;
  EXPECT_EQ(expand_sequence("fluid_{}.bgeo", 8, 10), (std::vector<P>{"fluid_8.bgeo", "fluid_9.bgeo", "fluid_10.bgeo"}));
  EXPECT_EQ(expand_sequence("out/f_{:04d}.ply", 0, 1), (std::vector<P>{"out/f_0000.ply", "out/f_0001.ply"}));
  EXPECT_EQ(expand_sequence("f{:03d}", -2, -2), (std::vector<P>{"f-02"}));
  EXPECT_EQ(expand_sequence("f{:3d}", 7, 7), (std::vector<P>{"f  7"}));
  EXPECT_EQ(expand_sequence("{{x}}_{}", 1, 1), (std::vector<P>{"{x}_1"}));
  EXPECT_EQ(expand_sequence("f_{:02d}", 123, 123), (std::vector<P>{"f_123"}));
  for (const std::string bad : {"fluid.bgeo", "f_{}_{}", "f_{:x}", "f_{", "f_}", "f_{:0d}", "f_{:99d}"}) {
    try {
      expand_sequence(bad, 0, 1);
      ADD_FAILURE() << bad;
    } catch (const Error& e) {
      EXPECT_EQ(e.field(), "pattern") << bad;
      EXPECT_NE(std::string(e.what()).find(bad), std::string::npos) << e.what();
    }
  }
  try {
    expand_sequence("f_{}", 5, 4);
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_EQ(e.field(), "end");
  }
  try {
    expand_sequence("f_{}", 0, 2000000);
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit);
  }
}

// --- Attributes ------------------------------------------------------------------------------------------------------

void expect_attribute(const ParticleFrame& f, const std::string& name, int components, const std::vector<float>& v) {
  const Attribute* a = find_attribute(f, name);
  ASSERT_NE(a, nullptr) << name << " not among " << attribute_list(f);
  EXPECT_EQ(a->components, components) << name;
  EXPECT_EQ(a->values, v) << name;
}

TEST(ParticleIo, VtkLegacyKeepsPointArraysAsAttributes) {
  const std::string text =
      "# vtk DataFile Version 3.0\nfluid\nASCII\nDATASET POLYDATA\nPOINTS 2 float\n0 0 0 1 0 0\n"
      "POINT_DATA 2\nSCALARS density float 1\nLOOKUP_TABLE default\n1000 998.5\n"
      "VECTORS velocity float\n1 2 3 4 5 6\nSCALARS radius float\nLOOKUP_TABLE default\n0.1 0.2\n"
      "FIELD FieldData 2\nfoam 1 2 float\n0 1\nstress 9 2 float\n0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0\n";
  const ParticleFrame f = parse_particles(text, ParticleFormat::kVtk, "a.vtk");
  EXPECT_EQ(f.radii, (std::vector<double>{0.1, 0.2}));
  expect_attribute(f, "density", 1, {1000.0f, 998.5f});
  expect_attribute(f, "velocity", 3, {1, 2, 3, 4, 5, 6});
  expect_attribute(f, "foam", 1, {0, 1});
  EXPECT_EQ(find_attribute(f, "stress"), nullptr);  // 9 components: a tensor, not kept
  EXPECT_EQ(find_attribute(f, "radius"), nullptr);
  EXPECT_EQ(attribute_list(f), "density (1), velocity (3), foam (1)");
}

TEST(ParticleIo, VtuKeepsPointDataOfEveryPiece) {
  VtuStyle st;
  std::string s = "<VTKFile type=\"PolyData\">\n<PolyData>\n";
  for (int piece = 0; piece < 2; ++piece) {
    const double o = piece;
    s += "<Piece NumberOfPoints=\"2\">\n<PointData>\n";
    s += vtu_array({o, o + 0.5}, "density", 1, st);
    s += vtu_array({1, 2, 3, 4, 5, 6}, "velocity", 3, st);
    if (piece == 0) s += vtu_array({7, 8}, "only_first", 1, st);
    s += "</PointData>\n<Points>\n" + vtu_array({o, 0, 0, o, 1, 0}, "Points", 3, st) + "</Points>\n</Piece>\n";
  }
  s += "</PolyData>\n</VTKFile>\n";
  const ParticleFrame f = parse_particles(s, ParticleFormat::kVtu, "p.vtp");
  ASSERT_EQ(f.positions.size(), 4u);
  expect_attribute(f, "density", 1, {0, 0.5, 1, 1.5});
  expect_attribute(f, "velocity", 3, {1, 2, 3, 4, 5, 6, 1, 2, 3, 4, 5, 6});
  EXPECT_EQ(find_attribute(f, "only_first"), nullptr);
}

TEST(ParticleIo, PlyGroupsVectorPropertiesAndKeepsScalars) {
  const std::string text =
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
      "property float velocity_x\nproperty float velocity_y\nproperty float velocity_z\nproperty float density\n"
      "property float pscale\nend_header\n0 0 0 1 2 3 1000 0.1\n1 0 0 4 5 6 999 0.1\n";
  const ParticleFrame f = parse_particles(text, ParticleFormat::kPly, "p.ply");
  expect_attribute(f, "velocity", 3, {1, 2, 3, 4, 5, 6});
  expect_attribute(f, "density", 1, {1000, 999});
  EXPECT_EQ(f.attributes.size(), 2u);
}

TEST(ParticleIo, XyzHeaderColumnsBecomeAttributes) {
  const ParticleFrame f =
      parse_particles("x,y,z,density,tag\n0,0,0,2.5,a\n1,0,0,3.5,b\n", ParticleFormat::kXyz, "p.csv");
  expect_attribute(f, "density", 1, {2.5, 3.5});
  EXPECT_EQ(find_attribute(f, "tag"), nullptr);  // not numbers
  // A header whose extra columns have no rows under them (found by fuzz_particles: it indexed past the values).
  for (const char* text : {"x,y,z,density\n", "id,Z,y,x,psc0+AppendedDataale,0.25,9\n"}) {
    try {
      const ParticleFrame empty = parse_particles(text, ParticleFormat::kXyz, "h.csv");
      EXPECT_TRUE(empty.positions.empty());
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput) << e.what();
    }
  }
}

TEST(ParticleIo, BgeoKeepsFloatAndVectorPointAttributes) {
  const ParticleFrame f = sample_frame(true, 5);
  const ParticleFrame back = parse_particles(write_bgeo(f), ParticleFormat::kBgeo, "p.bgeo");
  expect_same(back, f);
  expect_attribute(back, "v", 3, std::vector<float>(15, 0.25f));
  EXPECT_EQ(find_attribute(back, "kind"), nullptr);    // an indexed string
  EXPECT_EQ(find_attribute(back, "pscale"), nullptr);  // the radius
}

TEST(ParticleIo, JsonObjectOfArraysCarriesRadiiAndAttributes) {
  const ParticleFrame f = parse_particles(
      "{\"positions\": [[0, 0, 0], [1, 0, 0]], \"radius\": [0.5, 0.25], \"velocity\": [[1, 2, 3], [4, 5, 6]],\n"
      " \"density\": [1000, 999]}",
      ParticleFormat::kJson, "p.json");
  ASSERT_EQ(f.positions.size(), 2u);
  EXPECT_EQ(f.positions[1], Vec3(1, 0, 0));
  EXPECT_EQ(f.radii, (std::vector<double>{0.5, 0.25}));
  expect_attribute(f, "velocity", 3, {1, 2, 3, 4, 5, 6});
  expect_attribute(f, "density", 1, {1000, 999});
  for (const char* bad : {"{\"density\": [1]}", "{\"positions\": [[0, 0, 0]], \"density\": [1, 2]}",
                          "{\"positions\": [[0, 0]]}", "{\"positions\": [[0, 0, 0]], \"v\": [[1, 2], [3]]}"}) {
    EXPECT_THROW(parse_particles(bad, ParticleFormat::kJson, "bad.json"), Error) << bad;
  }
}

}  // namespace
}  // namespace surfacer
