// The messages that show a grid: markers (surface, particles, springs, label) and the point cloud.
// Built from positions alone, without a master, so their content and size can be tested directly.
#pragma once

#include "modal_mass_spring/grid.h"

#include <Eigen/Core>
#include <ros/time.h>
#include <sensor_msgs/PointCloud2.h>
#include <visualization_msgs/MarkerArray.h>

#include <string>
#include <vector>

namespace modal_mass_spring
{

// A point as a message.
geometry_msgs::Point point(const Eigen::Vector3d& p);

// How one grid is drawn: which namespaces are sent and how they look.
struct MarkerOptions
{
  std::string frame_id = "world";
  std::string ns_prefix;  // prepended to every namespace ("linear/" in a comparison)
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();  // m, where the grid is drawn in frame_id
  bool surface = true;    // TRIANGLE_LIST, both windings, coloured by strain per vertex
  bool particles = true;  // SPHERE_LIST, fixed particles red
  bool springs = true;    // LINE_LIST, coloured by strain
  bool color_by_strain = true;
  double strain_scale = 0.1;  // |strain| drawn in full colour
  double particle_diameter = 0.03;
  double spring_width = 0.006;
  int surface_max_cells = 1600;  // above this, the surface skips rows and columns evenly
  bool ghost = false;            // a faint, uniform grey: the shadow reference
  std::string label;             // TEXT_VIEW_FACING above the grid when not empty
};

// The strain of each particle: the mean of (l - l0) / l0 over the springs that end at it.
Eigen::VectorXd particleStrains(const Grid& grid, const Eigen::Matrix3Xd& points);

// The rows (or columns) the surface is drawn through: every `stride`-th of 0..count-1 and always
// the last, with the stride the smallest that keeps (rows - 1) (cols - 1) cells within max_cells.
std::vector<int> surfaceLines(int count, int stride);
int surfaceStride(int rows, int cols, int max_cells);

// Markers of one grid at `points` (3 x N, grid coordinates; drawn at points + offset). A namespace
// that is switched off is sent as a DELETE so that a viewer drops what it drew before. `particle_strains`:
// particleStrains(grid, points) when the caller has them (a pass over every spring), else computed here.
visualization_msgs::MarkerArray makeMarkers(const Grid& grid, const MarkerOptions& options,
                                            const Eigen::Matrix3Xd& points, const ros::Time& stamp,
                                            const Eigen::VectorXd& particle_strains = Eigen::VectorXd());

// One point per particle at points + offset: x, y, z and strain (float32), and contact (int32): the
// collider the particle touched in the last step, -1 none (`contacts` empty: none anywhere).
sensor_msgs::PointCloud2 makePointCloud(const Eigen::Matrix3Xd& points, const Eigen::VectorXd& strains,
                                        const std::vector<int>& contacts, const Eigen::Vector3d& offset,
                                        const std::string& frame_id, const ros::Time& stamp);

}  // namespace modal_mass_spring
