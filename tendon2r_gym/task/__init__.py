"""What the arm is asked to do: the reference, the PD gains of its controller, random arms and
references, the reward terms and the observation layout."""
