from dynslam_cli import run

run()
