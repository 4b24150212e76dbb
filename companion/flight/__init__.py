"""Flying: from a re-timed plan to the setpoints PX4 receives. The autopilot link
(MAVSDK) and the setpoint sender process, the setpoint stream and what it commands
(plans, brakes, holds), the commander and its safety checks, the replanner that joins
each new trajectory onto the command and has it re-timed (docs/service.md)."""
