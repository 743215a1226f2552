#pragma once
// Conversions between the core's types and ROS messages, the checks that reject bad input
// messages, and the per-parameter config overrides from the parameter server.
#include <ros/node_handle.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/ColorRGBA.h>

#include <string>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete_ros {

/// Reads x/y/z of a PointCloud2 into `out`. Returns an empty string when the message is usable,
/// otherwise the reason it is not (wrong frame, empty, missing or non-float x/y/z, inconsistent
/// sizes, more than max_points points, NaN/Inf points); `out` is only written on success. Every
/// size is checked before anything is allocated, so a hostile header costs nothing.
std::string cloud_from_msg(const sensor_msgs::PointCloud2& msg, const std::string& expected_frame,
                           shotcrete::Cloud& out, std::size_t max_points);

/// PointCloud2 with float32 x, y, z, intensity (= TD in metres) and packed rgb (TD through the
/// colour map on [0, td_color_max_m]; TD <= 0 is grey: nothing left to spray there).
sensor_msgs::PointCloud2 cloud_to_msg(const shotcrete::Points& xyz, const Eigen::VectorXd& td_m,
                                      double td_color_max_m, const std::string& frame_id,
                                      const ros::Time& stamp);

/// The measured layer per cell (~thickness): float32 x, y, z (the cell's wall after spraying),
/// intensity (= thickness in metres), rgb (thickness through the colour map on [0, color_max_m]),
/// lod95 (the measurement's 95 % level of detection, m) and cell (the grid cell index, exact in a
/// float32 below 2^24).
sensor_msgs::PointCloud2 cells_to_msg(const shotcrete::Points& xyz, const Eigen::VectorXd& thickness_m,
                                      const Eigen::VectorXd& lod95_m, const std::vector<int>& cells,
                                      double color_max_m, const std::string& frame_id, const ros::Time& stamp);

/// Colour map for t in [0, 1] (blue -> cyan -> green -> yellow -> red), clamped outside.
std_msgs::ColorRGBA colormap(double t, float alpha = 1.0f);

/// Every parameter `<pnh>/<section>/<key>` of the config field table overrides that value of
/// `config`. Unknown keys under a section namespace, wrong types and out-of-range results throw
/// std::invalid_argument naming the parameter. Returns the names of the overridden keys.
std::vector<std::string> apply_param_overrides(const ros::NodeHandle& pnh, shotcrete::Config& config);

}  // namespace shotcrete_ros
