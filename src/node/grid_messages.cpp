// Markers and point cloud of a grid.
#include "grid_messages.h"

#include <sensor_msgs/point_cloud2_iterator.h>

#include <algorithm>
#include <cmath>

namespace modal_mass_spring
{
namespace
{

std_msgs::ColorRGBA rgba(float r, float g, float b, float a = 1.0f)
{
  std_msgs::ColorRGBA c;
  c.r = r;
  c.g = g;
  c.b = b;
  c.a = a;
  return c;
}

// From `rest` towards red when stretched, towards blue when compressed, full at |strain| = scale.
std_msgs::ColorRGBA strainColour(const std_msgs::ColorRGBA& rest, double strain, double scale)
{
  static const std_msgs::ColorRGBA stretched = rgba(1.0f, 0.1f, 0.05f), compressed = rgba(0.1f, 0.3f, 1.0f);
  const float t = static_cast<float>(std::min(1.0, std::abs(strain) / scale));
  const std_msgs::ColorRGBA& end = strain > 0.0 ? stretched : compressed;
  return rgba(rest.r + t * (end.r - rest.r), rest.g + t * (end.g - rest.g), rest.b + t * (end.b - rest.b), rest.a);
}

double springStrain(const Spring& spring, const Eigen::Matrix3Xd& points)
{
  return ((points.col(spring.j) - points.col(spring.i)).norm() - spring.rest_length) / spring.rest_length;
}

visualization_msgs::Marker baseMarker(const MarkerOptions& options, const std::string& name, int type,
                                      const ros::Time& stamp)
{
  visualization_msgs::Marker marker;
  marker.header.frame_id = options.frame_id;
  marker.header.stamp = stamp;
  marker.ns = options.ns_prefix + name;
  marker.id = 0;
  marker.type = type;
  marker.action = visualization_msgs::Marker::ADD;
  marker.pose.orientation.w = 1.0;
  return marker;
}

visualization_msgs::Marker deleted(const MarkerOptions& options, const std::string& name, const ros::Time& stamp)
{
  visualization_msgs::Marker marker = baseMarker(options, name, visualization_msgs::Marker::SPHERE_LIST, stamp);
  marker.action = visualization_msgs::Marker::DELETE;
  return marker;
}

}  // namespace

geometry_msgs::Point point(const Eigen::Vector3d& p)
{
  geometry_msgs::Point msg;
  msg.x = p.x();
  msg.y = p.y();
  msg.z = p.z();
  return msg;
}

Eigen::VectorXd particleStrains(const Grid& grid, const Eigen::Matrix3Xd& points)
{
  Eigen::VectorXd sum = Eigen::VectorXd::Zero(grid.numParticles());
  Eigen::VectorXi count = Eigen::VectorXi::Zero(grid.numParticles());
  for (const Spring& spring : grid.springs())
  {
    const double strain = springStrain(spring, points);
    sum[spring.i] += strain;
    sum[spring.j] += strain;
    ++count[spring.i];
    ++count[spring.j];
  }
  for (int k = 0; k < grid.numParticles(); ++k)
    if (count[k] > 0)
      sum[k] /= count[k];
  return sum;
}

int surfaceStride(int rows, int cols, int max_cells)
{
  const double cells = static_cast<double>(rows - 1) * (cols - 1);
  int stride = std::max(1, static_cast<int>(std::ceil(std::sqrt(cells / std::max(1, max_cells)))));
  // The last row and column are always drawn, which can add one line each: widen until it fits.
  while (stride < std::max(rows, cols) &&
         static_cast<double>(surfaceLines(rows, stride).size() - 1) * (surfaceLines(cols, stride).size() - 1) >
             max_cells)
    ++stride;
  return stride;
}

std::vector<int> surfaceLines(int count, int stride)
{
  std::vector<int> lines;
  for (int k = 0; k < count; k += stride)
    lines.push_back(k);
  if (lines.empty() || lines.back() != count - 1)
    lines.push_back(count - 1);
  return lines;
}

namespace
{

using visualization_msgs::Marker;

// How a grid is drawn: the options, its points and the colours they share.
struct MarkerStyle
{
  const MarkerOptions& options;
  const Eigen::Matrix3Xd& points;
  const ros::Time& stamp;
  bool strain_colours;  // by strain, not for the ghost
  float alpha;
  std_msgs::ColorRGBA ghost_colour;
  geometry_msgs::Point at(int k) const { return point(points.col(k) + options.offset); }
};

Marker particlesMarker(const Grid& grid, const MarkerStyle& style)
{
  const MarkerOptions& options = style.options;
  if (!options.particles)
    return deleted(options, "particles", style.stamp);
  Marker particles = baseMarker(options, "particles", Marker::SPHERE_LIST, style.stamp);
  particles.scale.x = particles.scale.y = particles.scale.z = options.particle_diameter;
  const std_msgs::ColorRGBA free_colour = rgba(0.2f, 0.5f, 1.0f, style.alpha),
                            fixed_colour = rgba(0.9f, 0.2f, 0.15f, style.alpha);
  particles.color = options.ghost ? style.ghost_colour : free_colour;
  particles.points.reserve(style.points.cols());
  for (int k = 0; k < style.points.cols(); ++k)
  {
    particles.points.push_back(style.at(k));
    if (!options.ghost)
      particles.colors.push_back(grid.isFixed(k) ? fixed_colour : free_colour);
  }
  return particles;
}

Marker springsMarker(const Grid& grid, const MarkerStyle& style)
{
  const MarkerOptions& options = style.options;
  if (!options.springs)
    return deleted(options, "springs", style.stamp);
  Marker springs = baseMarker(options, "springs", Marker::LINE_LIST, style.stamp);
  springs.scale.x = options.spring_width;
  const std_msgs::ColorRGBA rest = options.ghost ? style.ghost_colour : rgba(0.8f, 0.8f, 0.8f);
  springs.color = rest;
  springs.points.reserve(2 * grid.springs().size());
  for (const Spring& spring : grid.springs())
  {
    springs.points.push_back(style.at(spring.i));
    springs.points.push_back(style.at(spring.j));
    if (!style.strain_colours)
      continue;
    const std_msgs::ColorRGBA c = strainColour(rest, springStrain(spring, style.points), options.strain_scale);
    springs.colors.push_back(c);
    springs.colors.push_back(c);
  }
  return springs;
}

Marker surfaceMarker(const Grid& grid, const MarkerStyle& style,
                                         const Eigen::VectorXd& particle_strains)
{
  const MarkerOptions& options = style.options;
  const GridParams& g = grid.params();
  if (!(options.surface && g.rows > 1 && g.cols > 1))
    return deleted(options, "surface", style.stamp);
  Marker surface = baseMarker(options, "surface", Marker::TRIANGLE_LIST, style.stamp);
  surface.scale.x = surface.scale.y = surface.scale.z = 1.0;
  const std_msgs::ColorRGBA rest = options.ghost ? style.ghost_colour : rgba(0.85f, 0.8f, 0.65f);
  surface.color = rest;
  const int stride = surfaceStride(g.rows, g.cols, options.surface_max_cells);
  const std::vector<int> rows = surfaceLines(g.rows, stride), cols = surfaceLines(g.cols, stride);
  const bool strain_colours = style.strain_colours;
  const Eigen::VectorXd strains = !strain_colours             ? Eigen::VectorXd()
                                  : particle_strains.size() > 0 ? particle_strains
                                                                : particleStrains(grid, style.points);
  const size_t vertices = 12 * (rows.size() - 1) * (cols.size() - 1);
  surface.points.reserve(vertices);
  if (strain_colours)
    surface.colors.reserve(vertices);
  auto vertex = [&](int k) {
    surface.points.push_back(style.at(k));
    if (strain_colours)
      surface.colors.push_back(strainColour(rest, strains[k], options.strain_scale));
  };
  // Two triangles per cell, each in both windings: a viewer culls back faces and lights each side
  // by its own normal, so the sheet is seen from either side.
  for (size_t r = 0; r + 1 < rows.size(); ++r)
    for (size_t c = 0; c + 1 < cols.size(); ++c)
    {
      const int a = grid.particleIndex(rows[r], cols[c]), b = grid.particleIndex(rows[r], cols[c + 1]);
      const int d = grid.particleIndex(rows[r + 1], cols[c]), e = grid.particleIndex(rows[r + 1], cols[c + 1]);
      for (const int k : {a, d, b, b, d, e, a, b, d, b, e, d})
        vertex(k);
    }
  return surface;
}

Marker labelMarker(const Grid& grid, const MarkerStyle& style)
{
  const MarkerOptions& options = style.options;
  const GridParams& g = grid.params();
  Marker label = baseMarker(options, "label", Marker::TEXT_VIEW_FACING, style.stamp);
  // Readable beside the grid at the distance that shows it whole; centred above the top row, clear
  // of the grid (a sheet tilted towards the viewer would hide its lower lines) and of the frame names.
  label.scale.z = 0.02 + 0.05 * (std::max(g.rows, g.cols) - 1) * g.spacing;
  const Eigen::Vector3d top = 0.5 * (style.points.col(0) + style.points.col(g.cols - 1)) + options.offset;
  const double lines = 1.0 + std::count(options.label.begin(), options.label.end(), '\n');
  label.pose.position = point(top + Eigen::Vector3d(0.0, 0.0, 0.6 * lines * label.scale.z + g.spacing));
  label.color = rgba(1.0f, 1.0f, 1.0f);
  label.text = options.label;
  return label;
}

}  // namespace

visualization_msgs::MarkerArray makeMarkers(const Grid& grid, const MarkerOptions& options,
                                            const Eigen::Matrix3Xd& points, const ros::Time& stamp,
                                            const Eigen::VectorXd& particle_strains)
{
  const float alpha = options.ghost ? 0.4f : 1.0f;
  const MarkerStyle style{options, points, stamp, options.color_by_strain && !options.ghost, alpha,
                          rgba(0.4f, 0.9f, 1.0f, alpha)};
  visualization_msgs::MarkerArray array;
  array.markers.push_back(particlesMarker(grid, style));
  array.markers.push_back(springsMarker(grid, style));
  array.markers.push_back(surfaceMarker(grid, style, particle_strains));
  if (!options.label.empty())
    array.markers.push_back(labelMarker(grid, style));
  return array;
}

sensor_msgs::PointCloud2 makePointCloud(const Eigen::Matrix3Xd& points, const Eigen::VectorXd& strains,
                                        const std::vector<int>& contacts, const Eigen::Vector3d& offset,
                                        const std::string& frame_id, const ros::Time& stamp)
{
  sensor_msgs::PointCloud2 cloud;
  cloud.header.frame_id = frame_id;
  cloud.header.stamp = stamp;
  sensor_msgs::PointCloud2Modifier modifier(cloud);
  modifier.setPointCloud2Fields(5, "x", 1, sensor_msgs::PointField::FLOAT32, "y", 1, sensor_msgs::PointField::FLOAT32,
                                "z", 1, sensor_msgs::PointField::FLOAT32, "strain", 1, sensor_msgs::PointField::FLOAT32,
                                "contact", 1, sensor_msgs::PointField::INT32);
  modifier.resize(points.cols());
  cloud.height = 1;
  cloud.width = static_cast<uint32_t>(points.cols());
  cloud.is_dense = true;
  sensor_msgs::PointCloud2Iterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z"), strain(cloud, "strain");
  sensor_msgs::PointCloud2Iterator<int32_t> contact(cloud, "contact");
  for (int k = 0; k < points.cols(); ++k, ++x, ++y, ++z, ++strain, ++contact)
  {
    *contact = static_cast<size_t>(k) < contacts.size() ? contacts[k] : -1;
    const Eigen::Vector3d p = points.col(k) + offset;
    *x = static_cast<float>(p.x());
    *y = static_cast<float>(p.y());
    *z = static_cast<float>(p.z());
    *strain = static_cast<float>(strains[k]);
  }
  return cloud;
}

}  // namespace modal_mass_spring
