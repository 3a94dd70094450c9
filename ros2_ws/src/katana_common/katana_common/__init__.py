"""What every node of the Katana curiosity graph shares, so that each thing is done one way.

- `params`: declared, validated, live or read-only parameters (`Param`, `declare_parameters`,
  `ParameterError`).
- `node_runner`: `run_node`, every node's main(): start-up errors, signals, shutdown, exit codes.
- `qos`: the QoS profiles, named by purpose.
- `messages`: stamps and durations to and from seconds (message <-> value).
- `futures`: the bounded wait on an rclpy future from a callback thread.
- `executor`: the MultiThreadedExecutor every multi-threaded graph spins on (rclpy's without
  two busy loops of its spinning thread).
- `action_client`: the ActionClient every node uses (rclpy's with rclpy#1123 closed).
"""
