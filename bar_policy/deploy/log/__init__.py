"""The run's log and its file formats: one run directory per ``bar-deploy`` run, written, read and served.

- ``run_log``: ``RunLog``, the run directory (streaming ``run.mcap``, ``log.npz`` at close, ``run.json``);
- ``files``: the per-tick fields (``log_fields``), the log's errors and its durable file helpers;
- ``read``: ``load_log`` (``log.npz``, else ``run.mcap``, else older NPZ chunks);
- ``mcap_schema``, ``mcap_write``, ``mcap_read``, ``recover``: the MCAP file's topics and JSON Schemas, its
  writer, its reader (a file cut by a crash too) and its repair (``bar-deploy log recover``);
- ``channels``, ``ros2_schema``, ``foxglove_scene``: the same values in well-known schemas (ROS 2 joint
  states, the robot in Foxglove's 3D panel, log lines);
- ``live``: those channels served to the Foxglove app (``--live``);
- ``plot``: PNG plots of a run log (``bar-deploy plot``).
"""
