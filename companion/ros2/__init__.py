"""ROS 2 planners on Zenoh, with no ROS installed: the service reads and writes ROS
messages (CDR) on the key expressions of ``rmw_zenoh`` or ``zenoh-bridge-ros2dds``.

* :mod:`companion.ros2.settings`: the ``[ros2]`` configuration section;
* :mod:`companion.ros2.types`: message definitions, CDR (``rosbags``), type hashes;
* :mod:`companion.ros2.decode`: ROS input -> validated trajectories and maps (pure,
  picklable functions for the decoding worker);
* :mod:`companion.ros2.encode`: status and re-timed trajectory -> ROS messages;
* :mod:`companion.ros2.layout`: key expressions, liveliness tokens and attachments
  of both layouts;
* :mod:`companion.ros2.link`: the subscriptions, tokens and publishers on a session.
* :mod:`companion.ros2.send`: the planner's side for tools: a ROS message from a file,
  published as a ROS node of the layout would (``rota-gs send --ros2``).

User guide: ``docs/ros2.md``. This package imports nothing heavy at import time, so
:mod:`companion.settings.config` can import the settings.
"""
