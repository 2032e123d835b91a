// Particle files for the particle surfacer: positions and optional per-particle radii of one frame.
//
// Formats, chosen by extension (case-insensitive; a trailing ".gz" is ignored, and gzip data is recognised by its
// magic bytes 1f 8b whatever the extension, then inflated before parsing):
//   .xyz .txt .csv  text, one particle per line: "x y z" or "x y z r", separated by whitespace and/or commas;
//                   '#' starts a comment; an optional first line of column names (e.g. "x,y,z,radius,id") selects
//                   the x, y, z and radius (or pscale) columns by name. Binary data (a control byte other than
//                   tab, CR, LF, FF or VT in the first 4 KiB: splashsurf's raw float32 `.xyz`) is refused with a
//                   message that says to rename the file to .bin.
//   .ply            point cloud (ascii, binary_little_endian, binary_big_endian): element "vertex" with properties
//                   x, y, z of any scalar type and an optional radius or pscale; other properties/elements skipped.
//   .vtk            VTK legacy, DATASET POLYDATA or UNSTRUCTURED_GRID, ASCII or BINARY (big-endian): the POINTS
//                   (any numeric type); radii from a POINT_DATA SCALARS or FIELD array named radius or pscale.
//   .vtu .vtp       VTK XML UnstructuredGrid/PolyData: <Points><DataArray> of every <Piece>, format "ascii", inline
//                   "binary" (base64) or "appended" (<AppendedData encoding="raw"> or "base64"), with a UInt32 or
//                   UInt64 header, little- or big-endian, uncompressed or compressed with zlib, LZ4 or LZMA
//                   (vtkZLibDataCompressor, vtkLZ4DataCompressor, vtkLZMADataCompressor: VTK's default is appended
//                   base64 zlib, meshio's inline binary zlib), any numeric type; child elements after the values
//                   (<InformationKey>) skipped; radii from a PointData DataArray named radius or pscale. Compressed
//                   arrays inflate to at most ParticleReadLimits::max_bytes in all, and a block that claims more than
//                   zlib (1032:1) or LZ4 (255:1) can produce from its bytes is refused before anything is allocated.
//   .json           splashsurf's JSON: a list of [x, y, z] lists, e.g. [[0, 0, 0], [0.1, 0, 0]]; or an object of
//                   per-particle lists {"positions": [[x, y, z], ...], "radius": [r, ...], "velocity": [[u, v, w],
//                   ...], ...} (a radius or pscale list gives the radii, every other list an attribute).
//   .bin            raw little-endian float32 x y z triples, no header.
//   .bgeo .bhclassic  Houdini classic binary geometry (magic "Bgeo", version 5; as written by Partio and
//                   SPlisHSPlasH): the point positions, radii from a float point attribute named pscale or radius.
//
// Attributes (ParticleFrame::attributes): every other per-point array of 1 to 4 numbers is kept under its name, as
// float32: VTK legacy POINT_DATA SCALARS, VECTORS, NORMALS and FIELD arrays; VTK XML PointData DataArrays (kept when
// every <Piece> has them); PLY vertex properties (NAME_x, NAME_y, NAME_z ... in a row make one vector NAME); BGEO
// float and int point attributes; named columns of .xyz/.csv text; the lists of a .json object. Arrays of other sizes
// (tensors) and string arrays are skipped; .bin carries none. Values are converted to float32 as they are and not
// checked: whoever uses an array checks it (the client, before it uploads the arrays named by --interpolate).
//
// Every problem (unreadable file, unknown extension, bad syntax, wrong counts, truncation, non-finite coordinates,
// unsupported variant) throws surfacer::Error(kInvalidInput, "file") whose message starts with the file name and names
// the line (text) or byte offset (binary; offsets of gzip data are into the inflated bytes), e.g.
//   "fluid_0003.bgeo: byte 131: truncated point 2 of 1000 (needs 28 bytes, 5 left)".
// Headers are never trusted: reservations are capped by the bytes present, so hostile files cannot exhaust memory.
// What a file may amount to is bounded by ParticleReadLimits: past its bytes (a plain file's size, gzip data as it
// inflates, checked as it goes, so a small bomb stops at the limit) or particles, or when inflating runs out of
// memory, ResourceLimit("file") names the file and the limit.
#pragma once

#include <cstdint>
#include <filesystem>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "core/mesh/mesh.h"

namespace surfacer {

struct ParticleFrame {
  std::vector<Vec3> positions;
  std::vector<double> radii;  // empty, or one per position (as stored; not validated here)
  // The file's other per-particle arrays of 1 to Attribute::kMaxComponents numbers (velocity, density, ...), one
  // element per position each, under the file's names, in file order (see "Attributes" above).
  std::vector<Attribute> attributes;
};

// The attribute named `name` of `frame`, or nullptr.
const Attribute* find_attribute(const ParticleFrame& frame, std::string_view name);
// "velocity (3), density (1)", or "none": the attributes a frame has, for messages.
std::string attribute_list(const ParticleFrame& frame);

enum class ParticleFormat { kXyz, kPly, kVtk, kVtu, kBin, kBgeo, kJson };

struct ParticleReadLimits {
  std::uint64_t max_bytes = std::uint64_t{16} << 30;  // of the file's data, once inflated
  std::int64_t max_particles = std::numeric_limits<std::int64_t>::max();
};

// Format from the file name's extension (see above); throws InvalidInput("file") naming the supported extensions.
ParticleFormat particle_format_from_path(const std::filesystem::path& path);

ParticleFrame read_particles(const std::filesystem::path& path, const ParticleReadLimits& limits = {});
// The same from bytes in memory (gzip accepted); `name_for_errors` prefixes every message.
ParticleFrame parse_particles(std::string_view bytes, ParticleFormat format, const std::string& name_for_errors,
                              const ParticleReadLimits& limits = {});

// Frame file names from a pattern with one placeholder "{}" (the frame number as is) or "{:Nd}" / "{:0Nd}"
// (zero-padded to N digits; N in 1..18), for frames start..end inclusive, e.g.
//   expand_sequence("fluid_{:04d}.ply", 0, 2) -> fluid_0000.ply, fluid_0001.ply, fluid_0002.ply
// Negative frame numbers keep their sign ("-007" for {:04d}). "{{" and "}}" are literal braces. Files are not checked.
// Throws InvalidInput("pattern") without exactly one placeholder or with a malformed one, InvalidInput("end") when
// end < start, ResourceLimit("end") for more than 10^6 frames.
std::vector<std::filesystem::path> expand_sequence(const std::string& pattern, int start, int end);

}  // namespace surfacer
