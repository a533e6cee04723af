"""Expert demonstrators that drive the scenes from what a camera sees (paper section 3.3, Table 3).

detector  colour-cube detector on RGB (OpenCV HSV + chroma + connected components; the
          paper's YOLOv8 stand-in)
pid       PID with derivative on measurement, output limits, clamp/back-calculation
          anti-windup
nav       the navigation expert: two-axis PID on the detection, hold-then-search when lost
arm       the arm expert: wrist camera rgb + depth -> pre-grasp pose, HOME rule
rollout   in-process closed-loop nav episodes (tests, tools/checks/expert_study.py)
Modules are imported on use: a nav process never imports the arm code.
"""
