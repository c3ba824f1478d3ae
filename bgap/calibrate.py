from bgap.runner.numerics import command

main = command("bgap.calibration.calibrate")
if __name__ == "__main__":
    main()
