from bgap.runner.numerics import command

main = command("bgap.commands.calibrate")
if __name__ == "__main__":
    main()
