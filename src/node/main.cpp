// modal_mass_spring_node: a SimulationNode on the private parameters; a bad one ends it with ROS_FATAL.
#include "simulation_node.h"

#include <ros/ros.h>

#include <cstdio>

int main(int argc, char** argv)
{
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // log lines show up at once through pipes (run.sh, roslaunch)
  ros::init(argc, argv, "modal_mass_spring");
  ros::NodeHandle nh, private_nh("~");
  try
  {
    modal_mass_spring::SimulationNode node(nh, private_nh);
    ros::spin();
  }
  catch (const std::exception& error)
  {
    ROS_FATAL("%s", error.what());
    return 1;
  }
  return 0;
}
