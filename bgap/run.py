from bgap.runner.numerics import command

main = command("bgap.experiments.run")
if __name__ == "__main__":
    main()
