"""ROS 2 messages, written once, for every output that speaks ROS (MCAP recordings, Zenoh).

No ROS install is needed: the message definitions (``.msg`` text) live in
:mod:`drovisio.ros.msgdefs` and are encoded to CDR by ``mcap-ros2-support``.

Topics (relative to the drone's namespace; :mod:`drovisio.ros.messages`):

==================================  ======================================  ===================
topic                               type                                    frame_id
==================================  ======================================  ===================
``camera/image_raw/compressed``     ``sensor_msgs/msg/CompressedImage``     camera optical
``camera/camera_info``              ``sensor_msgs/msg/CameraInfo``          camera optical
``/tf_static``                      ``tf2_msgs/msg/TFMessage``              body → camera
``bricks``                          ``vision_msgs/msg/Detection3DArray``    camera optical
``target``                          ``geometry_msgs/msg/PoseWithCovarianceStamped``  body (FLU)
``output``                          ``std_msgs/msg/String``                 the JSON output
==================================  ======================================  ===================

Frames (:mod:`drovisio.ros.frames`): ROS bodies are FLU (REP 103), Drovisio's body is FRD
(MAVLink's): ``base_link`` is the FLU body, ``camera_optical_frame`` the camera with
OpenCV's axes (x right, y down, z forward — ROS's optical-frame convention, REP 103).
"""
