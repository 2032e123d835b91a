// PLY point clouds for core/particles/particle_io.h: the first "vertex" element's x, y, z, optional radius/pscale and
// other scalar properties as attributes (NAME_x NAME_y NAME_z [NAME_w], or NAME_0 NAME_1 ..., in a row: one vector),
// read through the one PLY reader (core/mesh/ply.h). Elements before it are read past; nothing after it is read.
#include <string>
#include <vector>

#include "core/mesh/ply.h"
#include "core/particles/particle_io_detail.h"

namespace surfacer::particle_io_detail {
namespace {

class PointReader final : public ply::ElementReader {
 public:
  PointReader(const ply::Element& vertex, const std::string& name) : vertex_(vertex), name_(name) {
    for (std::size_t p = 0; p < vertex.properties.size(); ++p) {
      const ply::Property& prop = vertex.properties[p];
      if (prop.list) continue;
      const int pi = static_cast<int>(p);
      if (prop.name == "x" && x_property_ < 0) x_property_ = pi;
      if (prop.name == "y" && y_property_ < 0) y_property_ = pi;
      if (prop.name == "z" && z_property_ < 0) z_property_ = pi;
      if (is_radius_name(prop.name) && radius_property_ < 0) radius_property_ = pi;
    }
    if (x_property_ < 0 || y_property_ < 0 || z_property_ < 0) {
      fail(name, line_at(vertex.header_line), "element 'vertex' lacks an x, y or z property");
    }
    group_attributes();
  }

  void begin(const ply::Element& e, std::size_t capacity) override {
    if (&e != &vertex_) return;
    frame_.positions.reserve(std::min<std::uint64_t>(e.count, capacity));
    if (radius_property_ >= 0) frame_.radii.reserve(frame_.positions.capacity());
  }

  void item(const ply::Element& e, const ply::Item& item) override {
    if (&e != &vertex_) return;
    const Vec3 p(item.scalars[static_cast<std::size_t>(x_property_)],
                 item.scalars[static_cast<std::size_t>(y_property_)],
                 item.scalars[static_cast<std::size_t>(z_property_)]);
    check_finite(p, name_, item.where.text() + " (vertex " + std::to_string(item.index) + ")");
    frame_.positions.push_back(p);
    if (radius_property_ >= 0) frame_.radii.push_back(item.scalars[static_cast<std::size_t>(radius_property_)]);
    for (Group& group : groups_) {
      for (int p : group.properties) group.values.push_back(item.scalars[static_cast<std::size_t>(p)]);
    }
  }

  bool last(const ply::Element& e) const override { return &e == &vertex_; }

  ParticleFrame take() {
    for (const Group& group : groups_) {
      keep_attribute(frame_, group.name, static_cast<std::int64_t>(group.properties.size()), group.values);
    }
    return std::move(frame_);
  }

 private:
  struct Group {
    std::string name;
    std::vector<int> properties;
    std::vector<double> values;
  };

  void group_attributes() {
    for (ply::AttributeProperties& a : ply::attribute_properties(vertex_, [&](int p) {
           return p == x_property_ || p == y_property_ || p == z_property_ || p == radius_property_;
         })) {
      groups_.push_back({std::move(a.name), std::move(a.properties), {}});
    }
  }

  std::vector<Group> groups_;
  const ply::Element& vertex_;
  const std::string& name_;
  int x_property_ = -1, y_property_ = -1, z_property_ = -1, radius_property_ = -1;
  ParticleFrame frame_;
};

}  // namespace

ParticleFrame parse_ply_points(std::string_view bytes, const std::string& name) {
  const ply::Header header = ply::parse_header(bytes, name);
  const ply::Element* vertex = nullptr;
  for (const ply::Element& e : header.elements) {
    if (e.name == "vertex") {
      vertex = &e;
      break;
    }
  }
  if (vertex == nullptr) fail(name, line_at(header.data_line - 1), "header declares no 'vertex' element");
  PointReader reader(*vertex, name);
  ply::read_data(bytes, header, reader, name);
  return reader.take();
}

}  // namespace surfacer::particle_io_detail
