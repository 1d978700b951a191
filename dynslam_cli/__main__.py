from dynslam_cli.cli import main

main()
